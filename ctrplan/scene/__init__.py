"""Planning scenes: anatomy, robot base pose, target and start, from scene files or label volumes.

The frozen scene objects (`objects`), pose geometry and patient directions
(`geometry`), scene files (`loader`), and scenes made from label volumes (`segmentation`: label
volumes to meshes; `labels`: those meshes into a scene file)."""
