"""Collision checking of a CTR backbone against the scene with FCL.

Modules: `capsules` (the backbone as capsules and the compiled kernels that place them), `world`
(the scene's FCL objects), `checker` (boolean checks, distances and clearances), `broadphase` (the
conservative distance grid).

The robot is a chain of capsules between consecutive backbone points; each capsule's radius is the
outer radius of the outermost tube present on that segment plus a configurable margin. Each obstacle
may carry its own margin (`Obstacle.margin_mm`): every boolean check against that obstacle tests the
capsule grown by it as well (the broadphase grid and the bounding boxes account for it too), so
planning, exact validation, repair and design keep that much more clearance from it without code of
their own. Distances are the raw ones (robot surface to obstacle, no margin);
`RobotCollisionChecker.structure_clearances` compares them with each structure's margin. The scene is
built once (meshes as BVHs of compact chunks, primitives as FCL shapes); the capsules are FCL objects
whose radius, length and pose are updated in place for every configuration (docs/design.md §4: building from
Python is slow, boolean checks are cheap, distances are for final paths only).

Boolean checks first ask the scene's conservative distance grid (`broadphase`) which capsules
are certainly clear of every obstacle -- for a whole batch of backbones in one compiled call -- and
send only the others to FCL, likeliest contact first: FCL judges every contact, so the answers are
those of FCL alone.
"""
