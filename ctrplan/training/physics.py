"""The Cosserat-rod equations (paper eq. 9-13) in torch, batched, for the PINN losses.

Same state layout and units as the shooting solver (`ctrplan.kinematics.backbone.STATE_NAMES`):
mm, N, 1/mm, rad, scalar-first quaternion. Every function takes per-sample arc length ``s`` (B,) in mm
and joints ``q`` (B, 6) with the robot's joint offset already applied.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ctrplan.robot import Robot

G_TO_N_PER_MM = 1e-9


@dataclass(frozen=True)
class TubeTensors:
    """Robot parameters as tensors (3,) on one device/dtype; ``weight`` (3, 3) N/mm, ``force`` (3,) N."""

    lengths: torch.Tensor
    straight: torch.Tensor
    kappa: torch.Tensor
    EI: torch.Tensor
    GJ: torch.Tensor
    weight: torch.Tensor
    force: torch.Tensor

    @classmethod
    def from_robot(cls, robot: Robot, device: torch.device | str = "cpu",
                   dtype: torch.dtype = torch.float32) -> TubeTensors:
        tubes = robot.tubes

        def t(values) -> torch.Tensor:
            return torch.as_tensor(np.asarray(values, dtype=float), dtype=dtype, device=device)

        mass = np.array([tb.density_kg_m3 * tb.area_mm2 for tb in tubes]) * G_TO_N_PER_MM
        return cls(
            lengths=t([tb.length_mm for tb in tubes]),
            straight=t([tb.straight_length_mm for tb in tubes]),
            kappa=t([tb.curvature_per_mm for tb in tubes]),
            EI=t([tb.bending_stiffness_nmm2 for tb in tubes]),
            GJ=t([tb.torsional_stiffness_nmm2 for tb in tubes]),
            weight=t(mass[:, None] * np.asarray(robot.loads.gravity_m_s2, dtype=float)[None, :]),
            force=t(robot.loads.tip_force_n),
        )


def segment_flags(s: torch.Tensor, q: torch.Tensor, tt: TubeTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """Which tubes are present (s < l_i) and curved at each arc length: two (B, 3) float masks."""
    beta = q[:, :3]
    ends = beta + tt.lengths
    present = (s[:, None] < ends).to(s.dtype)
    curved = present * (s[:, None] > beta + tt.straight).to(s.dtype)
    return present, curved


def quat_to_matrix(h: torch.Tensor) -> torch.Tensor:
    """Scalar-first quaternions (B, 4) -> rotation matrices (B, 3, 3)."""
    w, x, y, z = h.unbind(-1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rhs(x: torch.Tensor, s: torch.Tensor, q: torch.Tensor, tt: TubeTensors) -> torch.Tensor:
    """dx/ds (B, 15) of the 15-state x (B, 15) at arc lengths s (B,) for joints q (B, 6)."""
    present, curved = segment_flags(s, q, tt)
    mb = x[:, 0:2]
    uz = x[:, 2:5]
    th = x[:, 5:8]
    h = x[:, 11:15]
    c, sn = torch.cos(th), torch.sin(th)
    ek = tt.EI * tt.kappa * curved                       # (B, 3) N*mm
    bend = (tt.EI * present).sum(-1, keepdim=True)       # (B, 1)
    ux = (mb[:, 0:1] + (ek * c).sum(-1, keepdim=True)) / bend
    uy = (mb[:, 1:2] + (ek * sn).sum(-1, keepdim=True)) / bend
    duz = ek / tt.GJ * (sn * ux - c * uy)
    dth = present * (uz - uz[:, 0:1])
    u1z = uz[:, 0:1]
    hw, hx, hy, hz = h.unbind(-1)
    ux1, uy1, uz1 = ux[:, 0], uy[:, 0], u1z[:, 0]
    dh = 0.5 * torch.stack([
        -hx * ux1 - hy * uy1 - hz * uz1,
        hw * ux1 + hy * uz1 - hz * uy1,
        hw * uy1 + hz * ux1 - hx * uz1,
        hw * uz1 + hx * uy1 - hy * ux1,
    ], -1)
    R = quat_to_matrix(h)
    dp = R[:, :, 2]
    ends = q[:, :3] + tt.lengths
    n = tt.force + ((ends - s[:, None]).clamp(min=0)[:, :, None] * tt.weight).sum(1)  # robot frame, N
    nb = torch.einsum("bji,bj->bi", R, n)                                              # body frame
    mz = (present * tt.GJ * uz).sum(-1)
    # m_b' = -u x m_b - e3 x R^T n
    dmx = -(uy1 * mz - uz1 * mb[:, 1]) + nb[:, 1]
    dmy = -(uz1 * mb[:, 0] - ux1 * mz) - nb[:, 0]
    dmb = torch.stack([dmx, dmy], -1)
    return torch.cat([dmb, duz, dth, dp, dh], -1)


def initial_theta_and_quat(u0: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Paper eq. 10 and 12 from u_z(0) (B, 3): theta(0) (B, 3) and h(0) (B, 4)."""
    beta, alpha = q[:, :3], q[:, 3:]
    phi = alpha - beta * u0
    theta0 = phi - phi[:, 0:1]
    half = 0.5 * phi[:, 0]
    zero = torch.zeros_like(half)
    return theta0, torch.stack([torch.cos(half), zero, zero, torch.sin(half)], -1)
