"""The Cosserat-rod equations (paper eq. 9-13) in torch, batched, for the PINN losses.

Same state layout and units as the shooting solver (`ctrplan.kinematics.backbone.state_names`):
mm, N, 1/mm, rad, scalar-first quaternion; (2N + 9) states for N = 1…4 tubes. Every function takes
per-sample arc length ``s`` (B,) in mm and joints ``q`` (B, 2N) with the robot's joint offset already
applied. Tube parameters come from `ctrplan.kinematics.cosserat.RodArrays`, as for the shooting solver.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from ctrplan.kinematics.cosserat import RodArrays
from ctrplan.model.robot import Robot


@dataclass(frozen=True)
class TubeTensors:
    """`RodArrays` as tensors on one device/dtype: per tube (N,) lengths and straight lengths (mm),
    kappa (1/mm), EI and GJ (N*mm^2); ``weight`` (N, 3) N/mm, ``force`` (3,) N (robot frame),
    ``follower`` (3,) N (tip frame of tube 1); ``transmission``
    (N,) mm, how far behind the plate beyond -beta_i each tube twists (`Tube.transmission_length_mm`:
    it changes only the twist at s = 0)."""

    lengths: torch.Tensor
    straight: torch.Tensor
    kappa: torch.Tensor
    EI: torch.Tensor
    GJ: torch.Tensor
    weight: torch.Tensor
    force: torch.Tensor
    follower: torch.Tensor
    transmission: torch.Tensor
    has_follower: bool = False     # the robot's `Loads.has_follower`: known once, not read off a tensor

    @property
    def n_tubes(self) -> int:
        return self.lengths.shape[0]

    def tip_force(self, tip_rotation: torch.Tensor | None) -> torch.Tensor:
        """The tip force (B, 3) or (3,) N in the robot frame: the fixed force plus the follower force
        turned with the tip frames ``tip_rotation`` (B, 3, 3) (robot <- tip; None without a follower)."""
        if tip_rotation is None:
            return self.force
        return self.force + tip_rotation @ self.follower

    @classmethod
    def from_robot(cls, robot: Robot, device: torch.device | str = "cpu",
                   dtype: torch.dtype = torch.float32) -> TubeTensors:
        rod = RodArrays.of(robot)
        arrays = {f.name: getattr(rod, f.name) for f in fields(cls)
                  if f.name not in ("transmission", "has_follower")}
        arrays["transmission"] = [t.transmission_length_mm for t in robot.tubes]
        return cls(**{k: torch.as_tensor(np.asarray(v, dtype=float), dtype=dtype, device=device)
                      for k, v in arrays.items()}, has_follower=robot.loads.has_follower)


def segment_flags(s: torch.Tensor, q: torch.Tensor, tt: TubeTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """Which tubes are present (s < l_i) and curved at each arc length: two (B, N) float masks."""
    beta = q[:, :tt.n_tubes]
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


def rhs(x: torch.Tensor, s: torch.Tensor, q: torch.Tensor, tt: TubeTensors,
        tip_rotation: torch.Tensor | None = None) -> torch.Tensor:
    """dx/ds (B, 2N + 9) of the state x (B, 2N + 9) at arc lengths s (B,) mm for joints q (B, 2N);
    ``tip_rotation`` (B, 3, 3): the tip frames of tube 1 (robot <- tip) a follower force turns with."""
    n = tt.n_tubes
    present, curved = segment_flags(s, q, tt)
    mb = x[:, 0:2]
    uz = x[:, 2:2 + n]
    th = x[:, 2 + n:2 + 2 * n]
    h = x[:, 5 + 2 * n:9 + 2 * n]
    c, sn = torch.cos(th), torch.sin(th)
    ek = tt.EI * tt.kappa * curved                       # (B, N) N*mm
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
    ends = q[:, :n] + tt.lengths
    force = tt.tip_force(tip_rotation) + ((ends - s[:, None]).clamp(min=0)[:, :, None] * tt.weight).sum(1)
    nb = torch.einsum("bji,bj->bi", R, force)                                              # body frame
    mz = (present * tt.GJ * uz).sum(-1)
    # m_b' = -u x m_b - e3 x R^T n
    dmx = -(uy1 * mz - uz1 * mb[:, 1]) + nb[:, 1]
    dmy = -(uz1 * mb[:, 0] - ux1 * mz) - nb[:, 0]
    dmb = torch.stack([dmx, dmy], -1)
    return torch.cat([dmb, duz, dth, dp, dh], -1)


def initial_theta_and_quat(u0: torch.Tensor, q: torch.Tensor, tt: TubeTensors
                           ) -> tuple[torch.Tensor, torch.Tensor]:
    """Paper eq. 10 and 12 from u_z(0) (B, N): theta(0) (B, N) and h(0) (B, 4). Tube i twists over
    -beta_i + d_i behind the plate (d_i its transmission length, 0 unless measured)."""
    n = u0.shape[1]
    beta, alpha = q[:, :n] - tt.transmission, q[:, n:]
    phi = alpha - beta * u0
    theta0 = phi - phi[:, 0:1]
    half = 0.5 * phi[:, 0]
    zero = torch.zeros_like(half)
    return theta0, torch.stack([torch.cos(half), zero, zero, torch.sin(half)], -1)
