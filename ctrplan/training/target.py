"""The accuracy target of a trained PINN and the time it takes to get there (issue 40).

Target: tube-1 tip error over unseen configurations at most `ACCURACY_TARGET` mm at its 99.9th
percentile and at its maximum (what `ctrplan eval-model --n 5000` measures, and the card's final
evaluation).

While it trains, `ctrplan train` measures the network every `MONITOR_EVERY_S` seconds on a fixed set of
`MONITOR_CONFIGURATIONS` unseen configurations of their own seed (`MONITOR_SEED`: no training sampler,
evaluation or calibration uses it, and nothing is selected by it), so the card holds a time-to-target
curve. When the run ends short of the target, `time_to_target` says how far it got and, at the rate
measured over the last half of the run (a power law fitted to the curve there), how long it would
take -- an extrapolation, and labelled as one (likely short: the learning rate's cosine decay
steepens the last half of every run); none when the error stopped falling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot

#: Tube-1 tip error (mm) a trained model is meant to reach on unseen configurations.
ACCURACY_TARGET = {"tube1_tip_p99_9_mm": 0.5, "tube1_tip_max_mm": 1.0}
#: Which statistic of the tip error (`tail`) each target bounds.
TARGET_STATISTIC = {"tube1_tip_p99_9_mm": "p99_9", "tube1_tip_max_mm": "max"}
#: Seed of the monitor configurations (used nowhere else).
MONITOR_SEED = 731_406_225
MONITOR_CONFIGURATIONS = 5000
#: Seconds of training between two measurements of the curve.
MONITOR_EVERY_S = 30.0
#: Why an extrapolation from the last half of a run is likely short (the card and the terminal say it).
WHY_SHORT = "learning rate decays over that half, which steepens the curve there"
#: A power-law exponent above this (error ~ t^b) counts as "not falling": no extrapolation.
FLAT_EXPONENT = -0.05
#: Measurements in the last half of a run needed to fit its rate.
MIN_FIT_POINTS = 3


def tail(x: np.ndarray) -> dict:
    """mean, p99, p99.9 and max of errors (any shape)."""
    x = np.ravel(x)
    return {"mean": float(x.mean()), "p99": float(np.percentile(x, 99)),
            "p99_9": float(np.percentile(x, 99.9)), "max": float(x.max())}


def meets(tip_mm: dict) -> bool:
    """Whether a tube-1 tip error `tail` (mm) meets `ACCURACY_TARGET`."""
    return all(tip_mm.get(TARGET_STATISTIC[k]) is not None and tip_mm[TARGET_STATISTIC[k]] <= v
               for k, v in ACCURACY_TARGET.items())


@dataclass(frozen=True)
class CurvePoint:
    """The network's tube-1 tip error (mm; `tail`) on the monitor configurations at optimiser
    ``step``, ``time_s`` into the whole run."""

    time_s: float
    step: int
    tip_mm: dict

    def to_json(self) -> dict:
        return {"time_s": round(self.time_s, 1), "step": self.step,
                "tip_mm": {k: round(v, 4) for k, v in self.tip_mm.items()}}


class Monitor:
    """The network's tube-1 tip error on `MONITOR_CONFIGURATIONS` fixed unseen configurations: their
    exact tips are solved once, then each call costs one network pass (the tip row only)."""

    def __init__(self, robot: Robot, n: int = MONITOR_CONFIGURATIONS, seed: int = MONITOR_SEED):
        q = robot.sample_joints(n, rng=seed)
        exact = CosseratBackend(robot).forward(q, points=2, check=False)
        ok = exact.converged
        self.q = torch.as_tensor(robot.apply_offset(q[ok]), dtype=torch.float32)
        self.tips_mm = exact.tips_mm[ok, 0]
        self.curve: list[CurvePoint] = []

    @property
    def configurations(self) -> int:
        """Monitor configurations the exact solver solved (the ones measured)."""
        return len(self.q)

    def __call__(self, net: PinnNet, step: int, time_s: float) -> CurvePoint:
        dev = next(net.parameters()).device
        with torch.no_grad():
            x = net(torch.ones(len(self.q), device=dev), self.q.to(dev))
        tips = x[:, net.i_p:net.i_p + 3].double().cpu().numpy()
        point = CurvePoint(time_s, step, tail(np.linalg.norm(tips - self.tips_mm, axis=1)))
        self.curve.append(point)
        return point


def power_law(t: np.ndarray, err: np.ndarray) -> tuple[float, float]:
    """Least-squares fit of ``err = exp(a) t^b``: (a, b)."""
    b, a = np.polyfit(np.log(t), np.log(err), 1)
    return float(a), float(b)


def time_to_target(curve: list[CurvePoint], final_tip_mm: dict | None = None) -> dict:
    """The card's ``time_to_target``: the target, the curve, when the curve first met the target
    (``reached_at_s``, the run's clock) and, when it did not by the end, ``extrapolated_s``: the time
    at which power laws fitted to the last half of the curve (per target statistic) all meet it, at
    least the curve's end (None, with the ``reason``, when one of them does not fall or the curve is
    too short). ``final_tip_mm``, the tail the verdict judged (`accuracy_verdict`), decides
    ``meets_target`` at the end."""
    reached = next((p for p in curve if meets(p.tip_mm)), None)
    out = {"target_mm": dict(ACCURACY_TARGET), "monitor": {"configurations": MONITOR_CONFIGURATIONS,
                                                           "seed": MONITOR_SEED},
           "reached_at_s": None if reached is None else round(reached.time_s, 1),
           "curve": [p.to_json() for p in curve]}
    final = final_tip_mm if final_tip_mm is not None else (curve[-1].tip_mm if curve else None)
    if final is not None and meets(final):
        return out
    half = [p for p in curve if p.time_s >= curve[-1].time_s / 2] if curve else []
    ex = {"extrapolated_s": None, "exponents": {},
          "method": "power law err = c t^b fitted per target statistic to the last half of the curve; "
                    "an extrapolation at the rate measured, not a measurement, and likely short: the "
                    f"{WHY_SHORT}"}
    out["extrapolation"] = ex
    if len(half) < MIN_FIT_POINTS:
        ex["reason"] = f"{len(half)} measurement(s) in the last half of the run: too few to fit a rate"
        return out
    estimate = 0.0
    for key, value in ACCURACY_TARGET.items():
        stat = TARGET_STATISTIC[key]
        a, b = power_law(np.array([p.time_s for p in half]), np.array([p.tip_mm[stat] for p in half]))
        ex["exponents"][stat] = round(b, 3)
        if final[stat] <= value:
            continue
        if b > FLAT_EXPONENT:
            ex["reason"] = (f"the tip error's {stat.replace('_', '.')} did not fall over the last half of "
                            f"the run")
            return out
        estimate = max(estimate, math.exp((math.log(value) - a) / b))
    ex["extrapolated_s"] = round(max(estimate, curve[-1].time_s), 0)
    return out


def summary(card_time_to_target: dict, final_tip_mm: dict, run_s: float | None) -> str:
    """One sentence for the terminal: reached (when), or how far it got in the ``run_s`` seconds
    the run took (on the training clock) and the extrapolation."""
    t = card_time_to_target
    target = ", ".join(f"{TARGET_STATISTIC[k].replace('_', '.')} <= {v:g} mm"
                       for k, v in t["target_mm"].items())
    got = f"p99.9 {final_tip_mm['p99_9']:.3f} mm, max {final_tip_mm['max']:.3f} mm"
    if meets(final_tip_mm):
        when = (f"; the monitor curve first met it {t['reached_at_s'] / 60:.1f} min into the run"
                if t["reached_at_s"] is not None else "")
        return f"meets the accuracy target (tube-1 tip {target}): {got}{when}"
    ex = t.get("extrapolation") or {}
    if ex.get("extrapolated_s") is None:
        rate = f"{ex.get('reason', 'no rate measured')}: no estimate of when it would"
    else:
        rate = (f"EXTRAPOLATED at the rate measured over the last half of the run (power law), it "
                f"would take about {ex['extrapolated_s'] / 60:.0f} min in all, likely more (the {WHY_SHORT})")
    took = f" in {run_s / 60:.1f} min" if run_s else ""
    return f"misses the accuracy target (tube-1 tip {target}){took}: got {got}; {rate}"

