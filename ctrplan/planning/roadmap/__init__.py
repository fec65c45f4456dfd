"""Multi-query roadmaps: build a graph of valid states once per scene, answer targets in milliseconds.

`build` grows the roadmap (sharded over worker processes or Ray), `store` keeps it on disk with the
fingerprints of scene, robot and model, `query` connects a target to it and validates the path with
the exact model. All contact with the single-query planning code is in `_adapter`.
"""
