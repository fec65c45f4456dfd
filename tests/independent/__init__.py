"""Test helpers written apart from ctrplan's model code: a separate Cosserat integrator and measured
data with hidden effects implemented here, so `diagnose` is tested on data its own code did not make."""
