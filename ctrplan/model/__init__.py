"""The robot model: tubes, joint domain and loads, the causes that extend it, the measurement side.

Tubes, joint domain, loads and files (`robot`); the cause library, each cause a
physical extension of the model (`causes`); and the measurement side of a robot -- reported joints to
the mechanics to what the tracker sees (`measurement`)."""
