"""The PINN surrogate's network: the paper's MLP (6x100 tanh -> 2N + 9) maps (arc length, joints) to the
(2N + 9)-state of an N-tube robot (15 for three tubes). `ctrplan.kinematics.pinn.PinnBackend` evaluates a
trained one; `ctrplan.kinematics.model_file` stores it with its model card.

Two input encodings (``features``), for N = 1…4 tubes:

* ``paper`` -- 1 + 2N inputs: ``2 s/l1 - 1`` and the joints' box coordinates (`JointDomain`) scaled
  to [-1, 1] (7 for three tubes).
* ``equivariant`` (default) -- uses an exact symmetry of the mechanics: adding c to every alpha rotates
  the whole robot about z by c. The network sees ``2 s/l1 - 1``, the N translation box coordinates and
  ``cos, sin`` of ``alpha_i - alpha_f`` for the tubes i other than the frame tube f (the mechanics is
  2 pi-periodic in them), in the order ``cos(alpha_i - alpha_f)`` for i = 1…N without f, then the
  sines: 3N - 1 inputs (8 for three tubes), one dimension fewer to learn. Positions it predicts are
  rotated by ``Rz(alpha_f)``, orientations ``R`` (tube 1's material frame) are
  ``Rz(alpha_f) R_net Rz(alpha1 - alpha_f)`` (so that ``R_net(0)`` is near the identity for every
  frame tube), and the twist angles are ``theta_i = alpha_i - alpha1 + (learned deviation)``.
  Any tube can be the frame tube (``frame``, 0-based; the paper's robot and the default: tube 1): its
  rotation is then exact, and the network learns only what the others' rotations relative to it do.
  The trainer picks the tube whose rotation moves the tip most (`ctrplan.training.samples.frame_tube`):
  on a robot whose stiff outer tube swings the whole backbone, that motion costs the network nothing.
  With ``harmonics`` K > 1 the network also sees ``cos, sin`` of ``k (alpha_i - alpha_f)`` for
  k = 2…K (``cos`` for every k, then ``sin``): where two tubes are nearly opposed the shape changes
  over a few hundredths of a radian of their relative rotation, and the harmonics let the first layer
  resolve that. They cost nothing per node at inference (the first layer's per-configuration part is
  computed once per backbone).

The symmetry holds only when the loads are along z (`Loads.axisymmetric`). Otherwise (gravity across
the robot), and for what measured data shows beyond the mechanics (a tracker offset fixed in the
base frame, encoder errors), ``absolute_angles`` appends ``cos alpha_i, sin alpha_i`` for every tube:
`PinnNet.with_absolute_angles` adds them to a trained network with zero weights, so it starts as the
same function and can learn what breaks the symmetry.

A fixed joint (zero-width box interval) enters as the constant feature 0.

The output transform builds the known structure in exactly (hard constraints):
``p = s e3 + (s^2 / L_ref) * net_p`` (so p(0) = 0 and p'(0) = e3 for every configuration),
``theta1 = 0``, ``m_b = 0`` when the robot has no loads, and a unit quaternion.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn

from ctrplan.model.robot import Robot

P_REF_MM = 100.0
FEATURES = ("paper", "equivariant")


def n_inputs(features: str, n_tubes: int, harmonics: int = 1, absolute_angles: bool = False) -> int:
    """Network inputs of an encoding for N tubes: 1 + 2N (``paper``) or 3N - 1 (``equivariant``)
    plus 2 (K - 1)(N - 1) for ``harmonics`` K and 2N for ``absolute_angles``."""
    if features == "paper":
        return 1 + 2 * n_tubes
    extra = 2 * n_tubes if absolute_angles else 0
    return 3 * n_tubes - 1 + 2 * (harmonics - 1) * (n_tubes - 1) + extra


class PinnNet(nn.Module):
    """The MLP with its input normalisation and output transform. Works in float32 or float64.

    ``forward(sigma (B,), q (B, 2N)) -> state (B, 2N + 9)`` with ``sigma = s / l1`` in [0, 1] and q in
    mm/rad (offsets already applied). ``scales`` (2N + 9,) sets the size of each raw output.
    """

    def __init__(self, robot: Robot, hidden: int = 100, layers: int = 6,
                 scales: np.ndarray | None = None, features: str = "equivariant", harmonics: int = 1,
                 absolute_angles: bool | None = None, frame: int = 0):
        super().__init__()
        if features not in FEATURES:
            raise ValueError(f"features must be one of {sorted(FEATURES)}, got {features!r}")
        if harmonics < 1 or (harmonics > 1 and features != "equivariant"):
            raise ValueError(f"harmonics must be >= 1 (and > 1 only with equivariant features), "
                             f"got {harmonics}")
        if absolute_angles is None:  # what the robot's loads need
            absolute_angles = features == "equivariant" and not robot.loads.axisymmetric
        if absolute_angles and features != "equivariant":
            raise ValueError("absolute_angles extends the equivariant encoding (paper features are "
                             "absolute already)")
        if not 0 <= frame < robot.n_tubes or (frame and features != "equivariant"):
            raise ValueError(f"frame must be a tube index 0…{robot.n_tubes - 1} (other than 0 only with "
                             f"equivariant features), got {frame}")
        self.features_mode, self.harmonics, self.absolute_angles = features, harmonics, absolute_angles
        self.frame = frame
        self.n_tubes, self.n_states = robot.n_tubes, robot.n_states
        self.n_inputs = n_inputs(features, robot.n_tubes, harmonics, absolute_angles)
        dims = [self.n_inputs] + [hidden] * layers
        mods: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:], strict=True):
            mods += [nn.Linear(a, b), nn.Tanh()]
        mods.append(nn.Linear(hidden, self.n_states))
        self.mlp = nn.Sequential(*mods)
        for m in self.mlp:
            if isinstance(m, nn.Linear):
                nn.init.xavier_normal_(m.weight)
                nn.init.zeros_(m.bias)
        # start near the unit quaternion (rotated by Rz(alpha_f) when equivariant): the orientation
        # about the tangent does not show in positions, so a random start is slow to unlearn
        out, i_h = self.mlp[-1], 2 * self.n_tubes + 5
        with torch.no_grad():
            out.weight[i_h:] *= 0.1
            out.bias[i_h] = 1.0
        self.hidden, self.layers = hidden, layers
        self.register_buffer("box_lower", torch.tensor(robot.domain.box_lower, dtype=torch.float32))
        self.register_buffer("box_upper", torch.tensor(robot.domain.box_upper, dtype=torch.float32))
        # the robot's box transform (`JointDomain.box_from_joints`); not stored with the weights
        box_matrix = torch.tensor(robot.domain.box_from_joints, dtype=torch.float32)
        self.register_buffer("box_from_joints", box_matrix, persistent=False)
        self.register_buffer("lengths", torch.tensor(robot.lengths_mm, dtype=torch.float32))
        self.register_buffer("scales", torch.ones(self.n_states) if scales is None
                             else torch.tensor(scales, dtype=torch.float32))
        self.register_buffer("loaded", torch.tensor(float(not robot.loads.is_free)))

    @property
    def i_p(self) -> int:
        """Offset of the position p (3,) in the state: 2N + 2."""
        return 2 * self.n_tubes + 2

    def box(self, q: torch.Tensor) -> torch.Tensor:
        """Box coordinates (B, 2N) ``(betaN, betaN - betaN-1, …, beta2 - beta1, alpha1 … alphaN)`` of
        joints q (B, 2N), mm and rad."""
        return q @ self.box_from_joints.T

    def features(self, sigma: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """Normalised network input (B, 1 + 2N | 3N - 1); fixed box coordinates give 0."""
        n = self.n_tubes
        width = self.box_upper - self.box_lower
        fixed = width <= 0
        zq = 2 * (self.box(q) - self.box_lower) / torch.where(fixed, torch.ones_like(width), width) - 1
        zq = torch.where(fixed, torch.zeros_like(zq), zq)
        zs = 2 * sigma[:, None] - 1
        if self.features_mode == "paper":
            return torch.cat([zs, zq], -1)
        others = [i for i in range(n) if i != self.frame]
        dalpha = q[:, [n + i for i in others]] - q[:, n + self.frame:n + self.frame + 1]
        k = torch.arange(1, self.harmonics + 1, dtype=q.dtype, device=q.device)
        angles = (k[:, None, None] * dalpha[None]).transpose(0, 1).reshape(len(q), -1)  # (B, K (N - 1))
        parts = [zs, zq[:, :n], torch.cos(angles), torch.sin(angles)]
        if self.absolute_angles:
            parts += [torch.cos(q[:, n:]), torch.sin(q[:, n:])]
        return torch.cat(parts, -1)

    def with_absolute_angles(self, robot: Robot) -> PinnNet:
        """A copy that also sees ``cos, sin alpha_i`` (equivariant encoding only), with zero weights
        on them: the same function, free to learn what breaks the rotation symmetry."""
        if self.absolute_angles:
            return copy.deepcopy(self)
        net = PinnNet(robot, self.hidden, self.layers, self.scales.cpu().numpy(), self.features_mode,
                      self.harmonics, absolute_angles=True, frame=self.frame)
        state = {k: v.clone() for k, v in self.state_dict().items()}
        w = state["mlp.0.weight"]
        state["mlp.0.weight"] = torch.cat([w, torch.zeros(w.shape[0], 2 * self.n_tubes, dtype=w.dtype)], 1)
        net.load_state_dict(state)
        return net.to(w.device)

    def forward(self, sigma: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        n, ip = self.n_tubes, self.i_p
        raw = self.mlp(self.features(sigma, q)) * self.scales
        s = (sigma * (q[:, 0] + self.lengths[0]))[:, None]
        mb = raw[:, 0:2] * self.loaded
        uz = raw[:, 2:2 + n]
        theta = torch.cat([torch.zeros_like(raw[:, 2 + n:3 + n]), raw[:, 3 + n:ip]], -1)
        e3 = torch.zeros_like(raw[:, ip:ip + 3])
        e3[:, 2] = 1.0
        p = s * e3 + (s * s / P_REF_MM) * raw[:, ip:ip + 3]
        h = raw[:, ip + 3:ip + 7]
        h = h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        if self.features_mode == "equivariant":
            a1, af = q[:, n:n + 1], q[:, n + self.frame:n + self.frame + 1]
            theta = theta + torch.cat([torch.zeros_like(a1), q[:, n + 1:] - a1], -1)
            c, sn = torch.cos(af), torch.sin(af)
            p = torch.cat([c * p[:, 0:1] - sn * p[:, 1:2], sn * p[:, 0:1] + c * p[:, 1:2], p[:, 2:3]], -1)
            cr, sr = torch.cos(0.5 * (a1 - af)), torch.sin(0.5 * (a1 - af))  # h <- h (x) qz(alpha1 - alpha_f)
            w, x, y, z = h[:, 0:1], h[:, 1:2], h[:, 2:3], h[:, 3:4]
            w, x, y, z = cr * w - sr * z, cr * x + sr * y, cr * y - sr * x, cr * z + sr * w
            cw, sz = torch.cos(0.5 * af), torch.sin(0.5 * af)    # h <- qz(alpha_f) (x) h
            h = torch.cat([cw * w - sz * z, cw * x - sz * y, cw * y + sz * x, cw * z + sz * w], -1)
        return torch.cat([mb, uz, theta, p, h], -1)
