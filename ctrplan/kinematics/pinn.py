"""PINN surrogate backend: the paper's MLP (6x100 tanh -> 2N + 9) maps (arc length, joints) to the
(2N + 9)-state of an N-tube robot (15 for three tubes). Evaluation is one batched forward pass, so its
cost hardly depends on the configuration.

Two input encodings (``features``), for N = 1…4 tubes:

* ``paper`` -- 1 + 2N inputs: ``2 s/l1 - 1`` and the joints' box coordinates (`JointDomain`) scaled
  to [-1, 1] (7 for three tubes).
* ``equivariant`` (default) -- uses an exact symmetry of the mechanics: adding c to every alpha rotates
  the whole robot about z by c. The network sees ``2 s/l1 - 1``, the N translation box coordinates and
  ``cos, sin`` of ``alpha_i - alpha1`` for i = 2…N (the mechanics is 2 pi-periodic in them), in the
  order ``cos(alpha2 - alpha1) … cos(alphaN - alpha1), sin(alpha2 - alpha1) …``; positions and
  orientation it predicts are rotated by ``Rz(alpha1)`` and the twist angles are
  ``theta_i = alpha_i - alpha1 + (learned deviation)``. 3N - 1 inputs (8 for three tubes), one
  dimension fewer to learn. With ``harmonics`` K > 1 the network also sees ``cos, sin`` of
  ``k (alpha_i - alpha1)`` for k = 2…K (``cos`` for every k, then ``sin``): where two tubes are nearly
  opposed the shape changes over a few hundredths of a radian of their relative rotation, and the
  harmonics let the first layer resolve that. They cost nothing per node at inference (the first
  layer's per-configuration part is computed once per backbone).

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
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ctrplan.kinematics._pinn_infer import backbone_fields, backbones, backbones_chunked, body_points, infer
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend, Body, arc_fractions, tangent_of
from ctrplan.kinematics.blas import one_blas_thread
from ctrplan.kinematics.cosserat import RodArrays
from ctrplan.robot import Robot

P_REF_MM = 100.0
FEATURES = ("paper", "equivariant")
#: Model-card key of the calibrated backbone position error bound (`PinnBackend.error_bound`).
ERROR_BOUND_KEY = "backbone_error_bound"
#: Network nodes per backbone (`PinnBackend`). Measured on the shipped model (2000 configurations, 40
#: points): interpolated backbones lie within 0.26 mm of the network evaluated at every point (p99 of
#: the largest deviation per backbone 0.12 mm) and their error against the exact model is unchanged
#: (p80 / p99 of the largest error per backbone 0.444 / 0.956 mm vs 0.442 / 0.956 mm); 25 nodes
#: cost 35 % more for a 0.06 mm deviation. The calibrated bound is measured with these nodes.
DEFAULT_NODES = 15
#: Network rows (configurations x nodes) per block of batched inference: activations stay in L2.
CHUNK_ROWS = 512


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
                 absolute_angles: bool | None = None):
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
        self.features_mode, self.harmonics, self.absolute_angles = features, harmonics, absolute_angles
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
        # start near the unit quaternion (rotated by Rz(alpha1) when equivariant): the orientation
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
        dalpha = q[:, n + 1:] - q[:, n:n + 1]
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
                      self.harmonics, absolute_angles=True)
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
            a1 = q[:, n:n + 1]
            theta = theta + torch.cat([torch.zeros_like(a1), q[:, n + 1:] - a1], -1)
            c, sn = torch.cos(a1), torch.sin(a1)
            p = torch.cat([c * p[:, 0:1] - sn * p[:, 1:2], sn * p[:, 0:1] + c * p[:, 1:2], p[:, 2:3]], -1)
            cw, sz = torch.cos(0.5 * a1), torch.sin(0.5 * a1)    # h <- qz(alpha1) (x) h
            w, x, y, z = h[:, 0:1], h[:, 1:2], h[:, 2:3], h[:, 3:4]
            h = torch.cat([cw * w - sz * z, cw * x - sz * y, cw * y + sz * x, cw * z + sz * w], -1)
        return torch.cat([mb, uz, theta, p, h], -1)


class PinnBackend(Backend):
    """Backbones from a trained `PinnNet`: compiled float32 inference (`_pinn_infer`).

    ``nodes``: the network's arc lengths per backbone (the transition points among them); the
    requested points are filled in by physics-informed Hermite interpolation (see `_pinn_infer`),
    from the nodes they need only, so a point's value never depends on the other points requested.
    ``nodes=None`` evaluates the network at every point instead.

    Its own computations run with BLAS on a single thread (`ctrplan.kinematics.blas`; the rest of the
    process is left alone): the many small matrix products of single queries and planner edges lose
    far more to BLAS thread synchronisation than they gain, and large batches are parallelised across
    cache-sized chunks instead.

    Load with `PinnBackend.load(path_or_name, robot)`; the model card is checked against the robot
    and the weights' hash (see `ctrplan.kinematics.model_file`).
    """

    name = "pinn"
    partial_backbones_cheap = True

    def __init__(self, robot: Robot, net: PinnNet, card: dict | None = None, *,
                 nodes: int | None = DEFAULT_NODES):
        super().__init__(robot)
        n, ns = robot.n_tubes, robot.n_states
        if nodes is not None and nodes < 2 * n + 1:  # up to 2N segments between transition points
            raise ValueError(f"nodes must be None or at least {2 * n + 1}, got {nodes}")
        self.nodes = nodes
        self.net = net.eval().float()
        self.card = card or {}
        for p in self.net.parameters():
            p.requires_grad_(False)
        self._compiled = self._export(self.net)
        self._rod = RodArrays.of(robot).arrays()
        self._loaded = not robot.loads.is_free
        self._offset = np.asarray(robot.joint_offset, dtype=float)
        self._has_offset = bool(np.any(self._offset))
        self._intervals = nodes - 1 if nodes is not None else 0  # 0: the network at every point
        self._i_p = self.net.i_p
        # distal residual, as moment over tube-1 stiffness in 1/m, is max |weights * at_ends| with
        # at_ends the (N + 1, 2N + 9) states at l1 … lN and s = 0: u_iz(l_i) GJ_i / GJ_1, m_b(l1) / EI_1
        gj = np.array([t.torsional_stiffness_nmm2 for t in robot.tubes])
        self._residual_weights = np.zeros((n + 1, ns))
        self._residual_weights[np.arange(n), 2 + np.arange(n)] = gj / gj[0] * 1e3
        self._residual_weights[0, 0:2] = 1e3 / robot.tubes[0].bending_stiffness_nmm2
        # compile (or load from numba's cache) the kernels now, not inside a caller's timed loop
        q0 = np.zeros((CHUNK_ROWS + 1, 2 * n))
        q0[:, :n] = -1.0
        self._evaluate(q0[:1], np.zeros((1, 1)))
        self.forward(q0, 2, check=False)                  # more than one chunk: the parallel kernel
        self.forward(q0[:1], DEFAULT_POINTS, check=False)
        self.body(q0[:1], DEFAULT_POINTS, check=False)

    @staticmethod
    def _export(net: PinnNet) -> tuple:
        """Weights and constants for the compiled kernel `_pinn_infer.infer` (float32, x @ W layout)."""
        linear = [m for m in net.mlp if isinstance(m, nn.Linear)]

        def w(m: nn.Linear) -> np.ndarray:
            return np.ascontiguousarray(m.weight.detach().numpy().T, dtype=np.float32)

        def b(m: nn.Linear) -> np.ndarray:
            return m.bias.detach().numpy().astype(np.float32)

        hidden = linear[1:-1]
        return (net.box_from_joints.numpy().astype(float),
                net.box_lower.numpy().astype(float), net.box_upper.numpy().astype(float),
                float(net.lengths[0]), net.scales.numpy().astype(float), float(net.loaded),
                net.features_mode == "equivariant", net.harmonics, net.absolute_angles,
                w(linear[0]), b(linear[0]),
                np.ascontiguousarray(np.stack([w(m) for m in hidden])), np.stack([b(m) for m in hidden]),
                w(linear[-1]), b(linear[-1]))

    @classmethod
    def load(cls, model: str | Path | None = None, robot: Robot | None = None, *,
             nodes: int | None = DEFAULT_NODES) -> PinnBackend:
        from ctrplan.kinematics.model_file import load_model

        robot = robot or Robot.nominal()
        net, card = load_model(model, robot)
        return cls(robot, net, card, nodes=nodes)

    def describe(self) -> dict:
        return {"weights": self.card.get("weights_file"), "nodes": self.nodes}

    @property
    def error_bound(self) -> dict | None:
        return self.card.get(ERROR_BOUND_KEY)

    def _joints(self, q: np.ndarray, check: bool) -> tuple[np.ndarray, np.ndarray]:
        """Joints (B, 2N) as given (checked against the robot with ``check``) and as the model sees
        them (offsets applied, contiguous)."""
        q = np.atleast_2d(self.robot.check_joints(q) if check else np.asarray(q, dtype=float))
        return q, np.ascontiguousarray(q + self._offset if self._has_offset else q, dtype=float)

    @staticmethod
    def _writable_fractions(points: int | np.ndarray) -> np.ndarray:
        """`arc_fractions` as a writable array: one compiled kernel type."""
        return arc_fractions(points).copy()

    def _evaluate(self, q: np.ndarray, frac: np.ndarray) -> np.ndarray:
        """The network's states (B, F, 2N + 9) at arc fractions frac (B, F) for joints q (B, 2N) with
        offsets applied."""
        out = np.empty((frac.shape[0], frac.shape[1], self.robot.n_states))
        with one_blas_thread():
            infer(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(frac, dtype=float),
                  *self._compiled, out)
        return out

    def forward(self, q: np.ndarray, points: int | np.ndarray = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        q, qm = self._joints(q, check)
        frac = self._writable_fractions(points)
        n = frac.size
        nt, ns = self.robot.n_tubes, self.robot.n_states
        # network rows per backbone: at most the nodes, or every point plus the N tube ends and s = 0
        rows = self.nodes if self.nodes is not None else n + nt + 1
        states = np.empty((len(qm), n, ns))
        at_ends = np.empty((len(qm), nt + 1, ns))
        chunk = max(1, CHUNK_ROWS // rows)
        with one_blas_thread():
            if len(qm) <= chunk:
                backbones(qm, frac, self._intervals, self._compiled, self._rod, self._loaded, states, at_ends,
                          True)
            else:
                backbones_chunked(qm, frac, self._intervals, self._compiled, self._rod, self._loaded, states,
                                  at_ends, chunk)
        ends, s_mm, radius, finite, residual = backbone_fields(
            qm, frac, self.robot.lengths_mm, self.robot.outer_radii_mm, self._residual_weights, states,
            at_ends)
        ip = self._i_p
        return Backbone(
            q=q, s_mm=s_mm, state=states, tube_ends_mm=ends, tips_mm=at_ends[:, :nt, ip:ip + 3],
            radius_mm=radius, converged=finite, initial_state=at_ends[:, nt],
            iterations=np.zeros(len(qm), dtype=np.int64), residual=residual, backend=self.name,
        )

    def body(self, q: np.ndarray, points: int | np.ndarray, *, guess: np.ndarray | None = None,
             check: bool = True) -> Body:
        """The network at the nodes the points need and nothing else (no tube ends, no s = 0): a
        planner's single-state checks spend most of their time here. One thread (no chunking)."""
        _, qm = self._joints(q, check)
        with one_blas_thread():
            pos, radius, finite = body_points(qm, self._writable_fractions(points), self._intervals,
                                              self._compiled, self._rod, self._loaded,
                                              self.robot.outer_radii_mm)
        return Body(pos, radius, finite)

    def tip_and_tangent(self, q: np.ndarray, *, check: bool = True
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The network at the tip alone: one row per configuration, where a backbone costs a row
        for every tube end too (see `Backend.tip_and_tangent`)."""
        _, qm = self._joints(q, check)
        x = self._evaluate(qm, np.ones((len(qm), 1)))[:, 0]
        ip = self._i_p
        return x[:, ip:ip + 3], tangent_of(x[:, ip + 3:ip + 7]), np.isfinite(x).all(axis=1)

    def initial_states(self, q: np.ndarray) -> np.ndarray:
        """Predicted state at s = 0 (B, 2N + 9) for joints q (B, 2N): a warm start for shooting."""
        _, qm = self._joints(q, check=False)
        return self._evaluate(qm, np.zeros((len(qm), 1)))[:, 0]

    def tip_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tip of tube 1 (B, 3) mm, its Jacobian d tip / d q (B, 3, 2N) by autograd through the
        network, and validity (B,). (Forward differences through the compiled `forward` are cheaper
        on a CPU, so ``analytic_tip_jacobian`` stays False.)"""
        qm = torch.from_numpy(self.robot.apply_offset(np.atleast_2d(q)).astype(np.float32))
        one = torch.ones(len(qm))
        ip = self.net.i_p

        def tip(qq: torch.Tensor) -> torch.Tensor:
            return self.net(one[:1], qq[None])[0, ip:ip + 3]

        with torch.enable_grad():
            jac = torch.func.vmap(torch.func.jacrev(tip))(qm)
        with torch.inference_mode():
            tips = self.net(one, qm)[:, ip:ip + 3]
        tips = tips.numpy().astype(float)
        return tips, jac.detach().numpy().astype(float), np.isfinite(tips).all(axis=1)
