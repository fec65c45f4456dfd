"""A start that is not only valid but leads somewhere: `scene check --fix` (issue 41, item 4).

A collision-free start can leave the robot where the target cannot be reached through the anatomy
(a tube turned a quarter turn, the robot outside the face): `reaching_start` searches, with the
exact model, from the nearest valid candidates (`ctrplan.planning.scene_check.valid_starts`) and
keeps the first from which a path reaches the target.
"""

from __future__ import annotations

import numpy as np

from ctrplan.planning.scene_check import StartFix, valid_starts
from ctrplan.planning.search import search
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene

#: Searches from at most this many valid candidate starts, nearest first, with this work budget each
#: (exact model: about 4 s each on the reference machine).
FIX_CANDIDATES = 4
FIX_SEARCH_STATES = 20_000


def reaching_start(scene: Scene, checker: ConfigurationChecker, seed: int = 0) -> StartFix:
    """The nearest valid start (`valid_starts`) from which a search with ``checker`` (the exact
    model) reaches the target, trying the `FIX_CANDIDATES` nearest with `FIX_SEARCH_STATES` states
    each: a start that is merely collision-free may leave the robot where the target cannot be
    reached through the anatomy (outside the face)."""
    tried, hints = 0, None
    for start in valid_starts(scene, checker):
        out = search(checker, start=start, seed=seed, max_states=FIX_SEARCH_STATES, simplify=False,
                     goal_hints=hints)
        tried += 1
        if out.path_q is not None:
            return StartFix(start, tried, out.budget.states, FIX_SEARCH_STATES)
        hints = np.array(out.goals) if out.goals else hints
        if tried >= FIX_CANDIDATES:
            break
    return StartFix(None, tried, 0, FIX_SEARCH_STATES)
