"""What to change when a robot snaps: the relative rotation or translation that separates the
configurations `ctrplan.kinematics.stability.check_domain` flagged from the rest, and the robot-file
limit that keeps the safe part (issue 41, item 8).

Candidates: every relative rotation ``alphaJ - alphaI`` (I < J; wrapped to [-pi, pi], judged by its
size: snapping is symmetric in its sign) -- a limit ``alphaJ_minus_alphaI_rad: [-t, t]`` is a box
coordinate of the domain (`ctrplan.model.robot.JointDomain.relative_to`) -- and every translation
coordinate of the box (``beta3``, ``beta3 - beta2`` ...), limited from above or below. For each, the
threshold beyond which every flagged configuration lies, and the share of the checked
configurations on the safe side of it (none of them flagged, by construction). The candidate that
keeps the largest share is the advice; its limit sits one sweep step inside the threshold. The
advice is a hypothesis the sweeps support, not a certificate: the limited robot is checked again by
``ctrplan stability``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ctrplan.model.robot import Robot, robot_from_dict

#: Below this share of the checked configurations kept, no single coordinate explains the snaps.
MIN_KEPT_SHARE = 0.3


@dataclass(frozen=True)
class SnapAdvice:
    """Where the robot snaps and the limit that keeps the safe part: the coordinate (``alpha3 -
    alpha2``, ``beta3 - beta2``), its robot-file ``key`` and the ``interval`` (rad or mm) to give it,
    the flagged configurations' median value (``near``: |angle| in rad, or mm), the threshold they
    all lie beyond, the share of the checked configurations the limit keeps, and the advice in words."""

    coordinate: str
    key: str
    interval: tuple[float, float]
    near: float
    threshold: float
    kept_share: float
    text: str

    def to_json(self) -> dict:
        return {"coordinate": self.coordinate, "key": self.key, "interval": list(self.interval),
                "near": self.near, "threshold": self.threshold, "kept_share": self.kept_share,
                "text": self.text}

    def limited(self, robot: Robot) -> Robot:
        """``robot`` with this limit in its domain, named ``NAME_snapfree``: the robot file the advice
        describes (a hypothesis until `ctrplan stability` certifies it)."""
        data = robot.to_dict()
        data["domain"][self.key] = [round(v, 3) for v in self.interval]   # as the advice's text gives it
        data["name"] = f"{robot.name}_snapfree"
        return robot_from_dict(data, f"<{robot.name} limited by {self.key}>")


def snap_advice(robot: Robot, q: np.ndarray, flagged: np.ndarray, steps: int) -> SnapAdvice | None:
    """The advice for checked configurations ``q`` (K, 2N) of which ``flagged`` (K,) snap, from
    sweeps of ``steps`` configurations; None when nothing is flagged. When no coordinate keeps
    `MIN_KEPT_SHARE` of the configurations, the advice says so and points at the tubes."""
    flagged = np.asarray(flagged, dtype=bool)
    if not flagged.any():
        return None
    candidates = [*_rotation_candidates(robot, q, flagged, steps),
                  *_translation_candidates(robot, q, flagged, steps)]
    best = max(candidates, key=lambda c: c.kept_share, default=None)
    if best is None or best.kept_share < MIN_KEPT_SHARE:
        share = 0.0 if best is None else best.kept_share
        return SnapAdvice("", "", (0.0, 0.0), math.nan, math.nan, share,
                          f"the {int(flagged.sum())} flagged configurations are not confined to one relative "
                          f"rotation or translation (the best limit would keep {100 * share:.0f} % of the "
                          f"domain): change the tubes -- less curvature or shorter curved overlaps snap less "
                          f"(docs/design.md §1.4)")
    return best


def _rotation_candidates(robot: Robot, q: np.ndarray, flagged: np.ndarray, steps: int) -> list[SnapAdvice]:
    n = robot.n_tubes
    out = []
    for j in range(1, n):
        for i in range(j):
            size = np.abs(np.angle(np.exp(1j * (q[:, n + j] - q[:, n + i]))))  # |alphaJ - alphaI| in [0, pi]
            threshold = float(size[flagged].min())
            step = 2 * math.pi / max(steps - 1, 1)
            limit = threshold - step
            if limit <= 0:
                continue
            kept = float(np.mean(size < threshold))
            name, key = f"alpha{j + 1} - alpha{i + 1}", f"alpha{j + 1}_minus_alpha{i + 1}_rad"
            near = float(np.median(size[flagged]))
            text = (f"snaps near {name} = +-{math.degrees(near):.0f} deg: all {int(flagged.sum())} flagged "
                    f"configurations have |{name}| >= {math.degrees(threshold):.0f} deg, none of the "
                    f"{int(np.sum(size < threshold)):,} below; to keep the safe part, limit it in the robot "
                    f"file: domain: {{{key}: [{-limit:.3f}, {limit:.3f}]}} (+-{math.degrees(limit):.0f} deg, "
                    f"{100 * kept:.0f} % of the checked configurations), then run ctrplan stability on it "
                    f"again to certify it")
            out.append(SnapAdvice(name, key, (-limit, limit), near, threshold, kept, text))
    return out


def _translation_candidates(robot: Robot, q: np.ndarray, flagged: np.ndarray, steps: int) -> list[SnapAdvice]:
    n = robot.n_tubes
    box = robot.domain.to_box(q)
    out = []
    for c in range(n):
        lo, hi = robot.domain.bounds[c]
        if hi <= lo:
            continue
        x, step = box[:, c], (hi - lo) / max(steps - 1, 1)
        name, key = robot.domain.names[c], robot.domain.keys[c]
        for below in (True, False):  # keep x below every flagged value, or above
            threshold = float(x[flagged].min() if below else x[flagged].max())
            kept_mask = x < threshold if below else x > threshold
            limit = threshold - step if below else threshold + step
            if not lo <= limit <= hi:
                continue
            interval = (lo, limit) if below else (limit, hi)
            kept = float(np.mean(kept_mask))
            side = ">=" if below else "<="
            text = (f"snaps at {name} {side} {threshold:.1f} mm (all {int(flagged.sum())} flagged "
                    f"configurations, none of the {int(kept_mask.sum()):,} beyond); to keep the safe part, "
                    f"limit it in the robot file: domain: {{{key}: [{interval[0]:.2f}, {interval[1]:.2f}]}} "
                    f"({100 * kept:.0f} % of the checked configurations), then run ctrplan stability on it "
                    f"again to certify it")
            out.append(SnapAdvice(name, key, interval, float(np.median(x[flagged])), threshold, kept, text))
    return out
