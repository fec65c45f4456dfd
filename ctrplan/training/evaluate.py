"""Accuracy of a PINN against the exact Cosserat model on unseen configurations (paper IV-A).

The evaluation configurations come from their own seed stream (`EVAL_SEED`), which no training
sampler uses, so they are never seen in training.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.robot import Robot

EVAL_SEED = 918_273_645


@dataclass(frozen=True)
class Comparison:
    """Backbones of one set of configurations from a surrogate and from the exact model."""

    predicted: Backbone
    exact: Backbone

    @property
    def normalised_error_pct(self) -> np.ndarray:
        """|p_pred - p_exact| / s * 100 (B, N-1), at every backbone point after s = 0."""
        d = np.linalg.norm(self.predicted.positions_mm - self.exact.positions_mm, axis=-1)
        return 100.0 * d[:, 1:] / self.exact.s_mm[:, 1:]

    def metrics(self) -> dict:
        """Backbone error (% of arc length), tip errors of tubes 1…N (mm), u_z RMSE (1/m), RMSE of
        the twists theta_2…N (rad; 0 for one tube), orientation error (deg)."""
        n = self.exact.n_tubes
        e = self.normalised_error_pct
        tip = np.linalg.norm(self.predicted.tips_mm - self.exact.tips_mm, axis=-1)  # (B, N)
        pq, eq = self.predicted.quaternions, self.exact.quaternions
        angle = np.degrees(2 * np.arccos(np.clip(np.abs((pq * eq).sum(-1)), 0, 1)))
        ps, es = self.predicted.state, self.exact.state
        return {
            "configurations": len(self.exact),
            "backbone_error_pct": {"mean": float(e.mean()), "max": float(e.max()),
                                   "p95": float(np.percentile(e, 95))},
            "tip_error_mm": {f"tube{i + 1}": {"mean": float(tip[:, i].mean()), "max": float(tip[:, i].max())}
                             for i in range(n)},
            "u_z_rmse_1_per_m": float(np.sqrt(((ps[..., 2:2 + n] - es[..., 2:2 + n]) ** 2).mean()) * 1e3),
            "theta_rmse_rad": float(np.sqrt(((ps[..., 3 + n:2 + 2 * n] - es[..., 3 + n:2 + 2 * n]) ** 2
                                             ).mean())) if n > 1 else 0.0,
            "orientation_error_deg": {"mean": float(angle.mean()), "max": float(angle.max())},
        }


def compare(model: Backend, robot: Robot, n: int = 100, points: int = 100,
            seed: int = EVAL_SEED) -> Comparison:
    """Run ``model`` and the exact solver on ``n`` unseen snap-free configurations."""
    q = robot.sample_joints(n, rng=seed)
    exact = CosseratBackend(robot).forward(q, points)
    return Comparison(predicted=model.forward(q, points), exact=exact)
