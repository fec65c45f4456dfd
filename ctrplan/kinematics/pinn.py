"""PINN surrogate backend: backbones from a trained `ctrplan.kinematics.pinn_net.PinnNet` (the paper's
MLP; its input encodings and output transform are described there). Evaluation is one batched pass of
compiled float32 inference (`ctrplan.kinematics._pinn_infer`), so its cost hardly depends on the
configuration.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ctrplan.kinematics._pinn_infer import (
    backbone_fields,
    backbones,
    backbones_chunked,
    body_points,
    body_points_blocks,
    infer,
    infer_blocks,
)
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import (
    DEFAULT_POINTS,
    Backend,
    Body,
    Points,
    arc_fractions,
    kernel_array,
    tangent_of,
)
from ctrplan.kinematics.blas import one_blas_thread
from ctrplan.kinematics.cosserat import RodArrays
from ctrplan.kinematics.model_file import load_model
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot

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
#: Blocks of rows that a planner's batched calls (`PinnBackend.body`, `tip_and_tangent`) of at least
#: `BLOCKED_ROWS` configurations are split into, run in parallel where numba has threads (a plan
#: alone on the machine; a pinned worker has one thread). Fixed, so that a seeded plan is the same
#: on any number of threads. 2-vCPU Xeon, 8 distal half-backbones: 176 -> 105 us.
ROW_BLOCKS = 2
BLOCKED_ROWS = 4


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
        for rows in (1, BLOCKED_ROWS):                      # single and blocked kernels
            self._evaluate(q0[:rows], np.zeros((rows, 1)))
            self.body(q0[:rows], DEFAULT_POINTS, check=False)
        self.forward(q0, 2, check=False)                  # more than one chunk: the parallel kernel
        self.forward(q0[:1], DEFAULT_POINTS, check=False)

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
                net.frame if net.features_mode == "equivariant" else -1, net.harmonics, net.absolute_angles,
                w(linear[0]), b(linear[0]),
                np.ascontiguousarray(np.stack([w(m) for m in hidden])), np.stack([b(m) for m in hidden]),
                w(linear[-1]), b(linear[-1]))

    @classmethod
    def load(cls, model: str | Path | None = None, robot: Robot | None = None, *,
             nodes: int | None = DEFAULT_NODES) -> PinnBackend:
        robot = robot or Robot.nominal()
        net, card = load_model(model, robot)
        return cls(robot, net, card, nodes=nodes)

    def describe(self) -> dict:
        return {"weights": self.card.get("weights_file"), "nodes": self.nodes}

    @property
    def model_card(self) -> dict | None:
        return self.card

    @property
    def error_bound(self) -> dict | None:
        return self.card.get(ERROR_BOUND_KEY)

    def _joints(self, q: np.ndarray, check: bool) -> tuple[np.ndarray, np.ndarray]:
        """Joints (B, 2N) as given (checked against the robot with ``check``) and as the model sees
        them (offsets applied, contiguous)."""
        q = np.atleast_2d(self.robot.check_joints(q) if check else np.asarray(q, dtype=float))
        return q, kernel_array(q + self._offset if self._has_offset else q)

    def _evaluate(self, q: np.ndarray, frac: np.ndarray) -> np.ndarray:
        """The network's states (B, F, 2N + 9) at arc fractions frac (B, F) for joints q (B, 2N) with
        offsets applied."""
        out = np.empty((frac.shape[0], frac.shape[1], self.robot.n_states))
        q, frac = kernel_array(q), kernel_array(frac)
        with one_blas_thread():
            if len(q) >= BLOCKED_ROWS:
                infer_blocks(q, frac, self._compiled, out, ROW_BLOCKS)
            else:
                infer(q, frac, *self._compiled, out)
        return out

    def forward(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        q, qm = self._joints(q, check)
        frac = kernel_array(arc_fractions(points))
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

    def body(self, q: np.ndarray, points: Points, *, guess: np.ndarray | None = None,
             check: bool = True) -> Body:
        """The network at the nodes the points need and nothing else (no tube ends, no s = 0): a
        planner's checks spend most of their time here. Batches of `BLOCKED_ROWS` or more run in
        `ROW_BLOCKS` parallel blocks."""
        return self.body_query(points)(self._joints(q, check)[0])

    def body_query(self, points: Points) -> Callable[[np.ndarray], Body]:
        """`body` with the fractions, weights and rod arrays bound once (the planner's hot path)."""
        args = (kernel_array(arc_fractions(points)), self._intervals, self._compiled, self._rod, self._loaded,
                self.robot.outer_radii_mm)
        offset = self._offset if self._has_offset else None

        def query(q: np.ndarray) -> Body:
            qm = kernel_array(q if offset is None else q + offset)
            with one_blas_thread():
                if len(qm) >= BLOCKED_ROWS:
                    return Body(*body_points_blocks(qm, *args, ROW_BLOCKS))
                return Body(*body_points(qm, *args))

        return query

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
