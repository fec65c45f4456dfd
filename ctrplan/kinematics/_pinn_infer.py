"""Compiled PINN inference (numba + BLAS): the same computation as `PinnNet.forward`, without
per-operation framework overhead, and whole backbones from it. `PinnBackend` uses it; tests assert it
agrees with the torch net.

Backbones come either from the network at every requested point (``intervals = 0``) or from the
network at ``intervals + 1`` nodes only -- every transition point (tube ends, starts of curved parts)
is a node -- joined by cubic Hermite interpolation whose slopes are the Cosserat right-hand side
(`_shooting.rhs`) at the predicted node states ("physics-informed interpolation"; at ``s = 0`` the
position slope is ``e3`` exactly, the boundary condition the network's positions are built with).
Arc-length cost is then per node, not per output point, and only the nodes the requested points need
are evaluated: a point's value does not depend on which other points are asked for, so part of a
backbone (a distal stretch, the tip alone) costs part of the network.

Any tube count N = 1…4: shapes follow from the arrays (``box_lo`` (2N,), ``rod`` arrays (N,)); states
are (2N + 9)-vectors. ``rod`` holds plain arrays (`cosserat.RodArrays.arrays`): numba's parallel
``prange`` cannot take a tuple nested in a tuple argument.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ctrplan.kinematics._shooting import hermite, lay_nodes, rhs, segments
from ctrplan.kinematics.base import outer_radius

# Rational approximation of tanh used by Eigen for float32 (accurate to float32 rounding on the
# clamped range); unlike libm's tanh it vectorises -- in float32 constants, and with numpy's error
# model (no division-by-zero branch: the denominator is at least _B[0] > 0), and with exact division
# (no reciprocal approximation) so that a row's value does not depend on where it falls in a batch.
_CLAMP = np.float32(7.90531110763549805)
_A = tuple(np.float32(v) for v in (
    4.89352455891786e-03, 6.37261928875436e-04, 1.48572235717979e-05, 5.12229709037114e-08,
    -8.60467152213735e-11, 2.00018790482477e-13, -2.76076847742355e-16))
_B = tuple(np.float32(v) for v in (
    4.89352518554385e-03, 2.26843463243900e-03, 1.18534705686654e-04, 1.19825839466702e-06))


@njit(cache=True, fastmath={"nnan", "ninf", "nsz", "contract"}, error_model="numpy")
def _tanh_inplace(a):
    flat = a.reshape(-1)
    for i in range(flat.size):
        x = flat[i]
        x = _CLAMP if x > _CLAMP else x
        x = -_CLAMP if x < -_CLAMP else x
        x2 = x * x
        p = ((((((_A[6] * x2 + _A[5]) * x2 + _A[4]) * x2 + _A[3]) * x2 + _A[2]) * x2 + _A[1]) * x2
             + _A[0]) * x
        r = ((_B[3] * x2 + _B[2]) * x2 + _B[1]) * x2 + _B[0]
        flat[i] = p / r


@njit(cache=True, fastmath=True)
def infer(q, frac, box_M, box_lo, box_hi, length1, scales, loaded, frame, harmonics, absolute,
          W0, b0, Wh, bh, Wo, bo, out):
    """States ``out`` (B, F, 2N + 9) at arc fractions ``frac`` (B, F) for joints ``q`` (B, 2N).

    Weights are float32 and laid out for ``x @ W`` (in, out). ``frame`` selects the input encoding:
    -1 the paper's, else the equivariant one with that frame tube (0-based), ``harmonics`` K its
    relative-rotation harmonics and ``absolute`` its absolute-angle features (see
    `ctrplan.kinematics.pinn_net`); a fixed box coordinate (``box_lo == box_hi``) enters as 0.
    """
    zq = np.empty((frac.shape[0], W0.shape[0] - 1), dtype=np.float32)
    _encode(q, box_M, box_lo, box_hi, frame, harmonics, absolute, zq)
    h = _hidden(zq, frac, W0, b0, Wh, bh)
    _decode(q, frac, h @ Wo + bo, length1, scales, loaded, frame, out)


@njit(cache=True, fastmath=True)
def _encode(q, box_M, box_lo, box_hi, frame, harmonics, absolute, zq):
    """The per-configuration inputs ``zq`` (B, inputs - 1) of the first layer for joints q (B, 2N)
    (the arc-length input is `_hidden`'s): the box coordinates scaled to [-1, 1], or with a
    ``frame`` tube (>= 0, equivariant) the betas and the harmonics of the rotations relative to the
    frame tube (and ``absolute`` angles)."""
    nb = q.shape[0]
    nt = box_lo.shape[0] // 2
    box = np.empty(2 * nt)
    for b in range(nb):
        for i in range(2 * nt):  # box = M q (`JointDomain.box_from_joints`)
            v = 0.0
            for j in range(2 * nt):
                v += box_M[i, j] * q[b, j]
            box[i] = v
        for i in range(2 * nt):
            width = box_hi[i] - box_lo[i]
            box[i] = 2.0 * (box[i] - box_lo[i]) / width - 1.0 if width > 0.0 else 0.0
        if frame >= 0:  # betas, then cos(k da_i) for k = 1…K (k-major; i != frame), then the sines
            for i in range(nt):
                zq[b, i] = box[i]
            n_ang = harmonics * (nt - 1)
            for k in range(harmonics):
                for i in range(nt):
                    if i == frame:
                        continue
                    col = nt + k * (nt - 1) + (i if i < frame else i - 1)
                    angle = (k + 1) * (q[b, nt + i] - q[b, nt + frame])
                    zq[b, col] = math.cos(angle)
                    zq[b, col + n_ang] = math.sin(angle)
            if absolute:
                for i in range(nt):
                    zq[b, nt + 2 * n_ang + i] = math.cos(q[b, nt + i])
                    zq[b, nt + 2 * n_ang + nt + i] = math.sin(q[b, nt + i])
        else:
            for i in range(2 * nt):
                zq[b, i] = box[i]


@njit(cache=True, fastmath=True)
def _hidden(zq, frac, W0, b0, Wh, bh):
    """The last hidden layer (B * F, width) at arc fractions ``frac`` (B, F) from the per-configuration
    inputs ``zq``: the first layer splits into an arc-length column and a per-configuration part,
    computed once per row."""
    nb, nf = frac.shape
    cq = zq @ W0[1:] + b0
    ws = W0[0]
    h = np.empty((nb * nf, W0.shape[1]), dtype=np.float32)
    for b in range(nb):
        for f in range(nf):
            zs = np.float32(2.0 * frac[b, f] - 1.0)
            r = b * nf + f
            for j in range(h.shape[1]):
                h[r, j] = zs * ws[j] + cq[b, j]
    _tanh_inplace(h)
    for k in range(Wh.shape[0]):
        h = h @ Wh[k] + bh[k]
        _tanh_inplace(h)
    return h


@njit(cache=True, fastmath=True)
def _decode(q, frac, raw, length1, scales, loaded, frame, out):
    """States ``out`` (B, F, 2N + 9) from the raw network outputs (B * F, 2N + 9): scaled, positions
    built from their boundary condition at s = 0, quaternions normalised, and with a ``frame`` tube
    (>= 0, equivariant) rotated back by its angle (orientations: ``qz(alpha_f) h qz(alpha1 - alpha_f)``,
    see `PinnNet`), the twists offset by ``alpha_i - alpha1``."""
    nb, nf = frac.shape
    nt = q.shape[1] // 2
    ns = 2 * nt + 9
    i_th, i_p = 2 + nt, 2 + 2 * nt
    x = np.empty(ns)
    for b in range(nb):
        l1 = q[b, 0] + length1
        a1 = q[b, nt]
        af = q[b, nt + max(frame, 0)]
        ca, sa = math.cos(af), math.sin(af)
        ch, sh = math.cos(0.5 * af), math.sin(0.5 * af)
        cr, sr = math.cos(0.5 * (a1 - af)), math.sin(0.5 * (a1 - af))
        for f in range(nf):
            r = b * nf + f
            o = out[b, f]
            for i in range(ns):
                x[i] = raw[r, i] * scales[i]
            s = frac[b, f] * l1
            o[0] = x[0] * loaded
            o[1] = x[1] * loaded
            for i in range(nt):
                o[2 + i] = x[2 + i]
            o[i_th] = 0.0
            for i in range(1, nt):
                o[i_th + i] = x[i_th + i]
            px = s * s / 100.0 * x[i_p]
            py = s * s / 100.0 * x[i_p + 1]
            pz = s + s * s / 100.0 * x[i_p + 2]
            i_q = i_p + 3
            nq = math.sqrt(x[i_q] ** 2 + x[i_q + 1] ** 2 + x[i_q + 2] ** 2 + x[i_q + 3] ** 2)
            nq = max(nq, 1e-12)
            w, hx, hy, hz = x[i_q] / nq, x[i_q + 1] / nq, x[i_q + 2] / nq, x[i_q + 3] / nq
            if frame >= 0:
                for i in range(1, nt):
                    o[i_th + i] += q[b, nt + i] - a1
                px, py = ca * px - sa * py, sa * px + ca * py
                # h <- qz(alpha_f) (x) h (x) qz(alpha1 - alpha_f)
                w, hx, hy, hz = cr * w - sr * hz, cr * hx + sr * hy, cr * hy - sr * hx, cr * hz + sr * w
                w, hx, hy, hz = ch * w - sh * hz, ch * hx - sh * hy, ch * hy + sh * hx, ch * hz + sh * w
            o[i_p], o[i_p + 1], o[i_p + 2] = px, py, pz
            o[i_q], o[i_q + 1], o[i_q + 2], o[i_q + 3] = w, hx, hy, hz


@njit(cache=True)
def node_steps(breaks, total):
    """Intervals per segment (S,): ``total`` shared in proportion to the segment lengths of ``breaks``
    (S+1,), at least one each (largest remainder); needs ``total >= S``."""
    ideal = (breaks[1:] - breaks[:-1]) * (total / (breaks[-1] - breaks[0]))
    steps = np.maximum(1, np.floor(ideal)).astype(np.int64)
    while steps.sum() < total:
        steps[np.argmax(ideal - steps)] += 1
    while steps.sum() > total:
        excess = np.where(steps > 1, steps - ideal, -np.inf)
        steps[np.argmax(excess)] -= 1
    return steps


@njit(cache=True)
def node_layout(q, intervals, lengths, straight, EI):
    """Network nodes of one configuration q (2N,): ``nodes`` (intervals+1,) mm, ``seg_of`` (intervals,),
    per-segment ``present``, ``kc``, ``bend`` (see `_shooting.segments`) and ``end_node`` (N,)."""
    beta = q[:lengths.shape[0]].copy()
    breaks, present, kc, bend, _ = segments(beta, lengths, straight, EI)
    nodes, seg_of, end_node = lay_nodes(breaks, node_steps(breaks, intervals), beta + lengths)
    return nodes, seg_of, present, kc, bend, end_node


@njit(cache=True)
def backbones(q, out_frac, intervals, net, rod, loaded, states, at_ends, with_ends=True):
    """States ``states`` (B, P, 2N + 9) at arc fractions ``out_frac`` (P,) of l1 for joints q (B, 2N),
    and the network's states ``at_ends`` (B, N + 1, 2N + 9) at the tube ends l1 … lN and at s = 0
    (with ``with_ends`` only: otherwise ``at_ends`` is left alone and those rows cost nothing).

    ``intervals = 0``: the network at every point; otherwise Hermite interpolation between the
    network at ``intervals + 1`` nodes (see the module docstring). ``net`` is the weights tuple of
    `infer`, ``rod`` the arrays ``(lengths, straight, kappa, EI, GJ, force, weight, follower)`` of
    `cosserat.RodArrays`, ``loaded`` whether the robot carries loads. A follower force turns with the
    network's tip frame of tube 1 (the last node, then always evaluated).
    """
    lengths, straight, kappa, EI, GJ, force, weight, follower = rod
    if intervals == 0:
        _backbones_dense(q, out_frac, net, lengths, states, at_ends, with_ends)
        return
    nb, nt = q.shape[0], lengths.shape[0]
    if nb == 0:
        return
    ns, i_p = 2 * nt + 9, 2 + 2 * nt
    # the first row's layout once for both passes (a planner's single-state call has one row)
    first = node_layout(q[0], intervals, lengths, straight, EI)
    # the network only at the nodes the requested points need (and with ``with_ends`` at `at_ends`')
    need, node_frac = _needed_nodes(q, out_frac, intervals, lengths, straight, EI, with_ends, first[0],
                                    first[5])
    has_follower = np.any(follower != 0.0)
    if has_follower:
        need[:, intervals] = True
    y = _network_at_nodes(q, need, node_frac, net, ns)
    row_force = force.copy()
    fl = np.empty((intervals, ns))
    fr_ = np.empty((intervals, ns))
    for b in range(nb):  # the layout again: cheaper than keeping ragged per-segment tables
        if b == 0:
            nodes, seg_of, present, kc, bend, end_node = first
        else:
            nodes, seg_of, present, kc, bend, end_node = node_layout(q[b], intervals, lengths, straight, EI)
        ends = q[b, :nt] + lengths
        yb = y[b]
        if has_follower:
            _turned_follower(yb[intervals, ns - 4:], force, follower, row_force)
        fl[:] = 0.0
        fr_[:] = 0.0
        for j in range(intervals):
            if not (need[b, j] and need[b, j + 1]):
                continue
            k = seg_of[j]
            rhs(nodes[j], yb[j], present[k], kc[k], kappa, bend[k], EI, GJ, ends, row_force, weight, loaded,
                True, fl[j])
            rhs(nodes[j + 1], yb[j + 1], present[k], kc[k], kappa, bend[k], EI, GJ, ends, row_force, weight,
                loaded, True, fr_[j])
        fl[0, i_p] = 0.0
        fl[0, i_p + 1] = 0.0
        fl[0, i_p + 2] = 1.0
        hermite(nodes, seg_of, yb, fl, fr_, out_frac * nodes[-1], states[b])
        if with_ends:
            for i in range(nt):
                at_ends[b, i] = yb[end_node[i]]
            at_ends[b, nt] = yb[0]


@njit(cache=True)
def _turned_follower(h, force, follower, out):
    """``out`` (3,) = ``force`` + R(h) ``follower``: the robot-frame tip force of a follower force
    (tip frame) at the tip orientation h (scalar-first quaternion, normalised here)."""
    n = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2] + h[3] * h[3])
    w, x, y, z = h[0] / n, h[1] / n, h[2] / n, h[3] / n
    fx, fy, fz = follower[0], follower[1], follower[2]
    out[0] = force[0] + (1 - 2 * (y * y + z * z)) * fx + 2 * (x * y - w * z) * fy + 2 * (x * z + w * y) * fz
    out[1] = force[1] + 2 * (x * y + w * z) * fx + (1 - 2 * (x * x + z * z)) * fy + 2 * (y * z - w * x) * fz
    out[2] = force[2] + 2 * (x * z - w * y) * fx + 2 * (y * z + w * x) * fy + (1 - 2 * (x * x + y * y)) * fz


@njit(cache=True)
def _backbones_dense(q, out_frac, net, lengths, states, at_ends, with_ends):
    """`backbones` with the network at every requested point (``intervals = 0``)."""
    nb, n = q.shape[0], out_frac.shape[0]
    nt = lengths.shape[0]
    ns = 2 * nt + 9
    extra = nt + 1 if with_ends else 0
    frac = np.empty((nb, n + extra))
    for b in range(nb):
        frac[b, :n] = out_frac
        if with_ends:
            for i in range(nt):
                frac[b, n + i] = (q[b, i] + lengths[i]) / (q[b, 0] + lengths[0])
            frac[b, n + nt] = 0.0
    y = np.empty((nb, n + extra, ns))
    infer(q, frac, *net, y)
    states[:] = y[:, :n]
    if with_ends:
        at_ends[:] = y[:, n:]


@njit(cache=True)
def _needed_nodes(q, out_frac, intervals, lengths, straight, EI, with_ends, first_nodes, first_end_node):
    """Which of the ``intervals + 1`` nodes of each configuration the requested points need ``need``
    (B, intervals + 1): those bracketing a point (the node itself for a point on a node), and with
    ``with_ends`` the tube ends and s = 0; and the nodes' arc fractions ``node_frac`` (B, intervals + 1).
    ``first_nodes``, ``first_end_node``: the first row's `node_layout` nodes and end nodes (computed
    by the caller, which needs them too)."""
    nb, n = q.shape[0], out_frac.shape[0]
    nt = lengths.shape[0]
    m = intervals
    need = np.zeros((nb, m + 1), dtype=np.bool_)
    node_frac = np.empty((nb, m + 1))
    for b in range(nb):
        if b == 0:
            nodes, end_node = first_nodes, first_end_node
        else:
            nodes, _, _, _, _, end_node = node_layout(q[b], intervals, lengths, straight, EI)
        node_frac[b] = nodes / nodes[-1]
        if with_ends:
            need[b, 0] = True
            for i in range(nt):
                need[b, end_node[i]] = True
        j = 0
        for p in range(n):
            s = out_frac[p] * nodes[-1]
            while j < m - 1 and s > nodes[j + 1]:
                j += 1
            if s <= nodes[j]:
                need[b, j] = True
            elif s >= nodes[j + 1]:
                need[b, j + 1] = True
            else:
                need[b, j] = True
                need[b, j + 1] = True
    return need, node_frac


@njit(cache=True)
def _network_at_nodes(q, need, node_frac, net, ns):
    """The network's states (B, intervals + 1, ns) at the needed nodes, in one batched call; nodes
    not needed stay 0 (Hermite weighs them by exactly 0)."""
    nb, m = need.shape[0], need.shape[1] - 1
    rows = np.flatnonzero(need.ravel())
    qr = np.empty((rows.size, q.shape[1]))
    fr = np.empty((rows.size, 1))
    for r in range(rows.size):
        b, j = rows[r] // (m + 1), rows[r] % (m + 1)
        qr[r] = q[b]
        fr[r, 0] = node_frac[b, j]
    yr = np.empty((rows.size, 1, ns))
    infer(qr, fr, *net, yr)
    y = np.zeros((nb, m + 1, ns))
    for r in range(rows.size):
        y[rows[r] // (m + 1), rows[r] % (m + 1)] = yr[r, 0]
    return y


@njit(cache=True, parallel=True)
def backbones_chunked(q, out_frac, intervals, net, rod, loaded, states, at_ends, chunk):
    """`backbones` over cache-sized chunks of ``chunk`` configurations, chunks in parallel (run it
    with single-threaded BLAS: the parallelism is across chunks)."""
    nb = q.shape[0]
    for c in prange((nb + chunk - 1) // chunk):
        a = c * chunk
        b = min(nb, a + chunk)
        backbones(q[a:b], out_frac, intervals, net, rod, loaded, states[a:b], at_ends[a:b], np.bool_(True))


@njit(cache=True)
def _along(qm, out_frac, lengths, outer_radii):
    """Tube ends (B, N) mm of joints qm (B, 2N) (offsets applied), arc lengths (B, P) mm of the
    fractions ``out_frac`` (P,) of l1, and the outer radius there (B, P) mm (outermost tube present)."""
    ends = qm[:, :lengths.shape[0]] + lengths
    s_mm = ends[:, :1] * out_frac.reshape((1, -1))
    radius = np.empty(s_mm.shape)
    outer_radius(s_mm, ends, outer_radii, radius)
    return ends, s_mm, radius


@njit(cache=True)
def backbone_fields(qm, out_frac, lengths, outer_radii, residual_weights, states, at_ends):
    """The rest of a `Backbone` from `backbones`' output, in one pass: tube ends (B, N) mm, arc
    lengths (B, P) mm, outer radius along the backbone (B, P) mm (outermost tube present), whether
    each row is finite (B,) and the distal residual max |residual_weights * at_ends| (B,)."""
    nb = states.shape[0]
    ends, s_mm, radius = _along(qm, out_frac, lengths, outer_radii)
    finite = np.ones(nb, dtype=np.bool_)
    residual = np.zeros(nb)
    for b in range(nb):
        for p in range(states.shape[1]):
            for k in range(states.shape[2]):
                if not math.isfinite(states[b, p, k]):
                    finite[b] = False
        for i in range(at_ends.shape[1]):
            for k in range(at_ends.shape[2]):
                v = abs(at_ends[b, i, k] * residual_weights[i, k])
                if v > residual[b] or not math.isfinite(v):
                    residual[b] = v
    return ends, s_mm, radius, finite, residual


@njit(cache=True)
def _body_fields(q, out_frac, rod, outer_radii, states):
    """Positions (B, P, 3) mm, outer radius (B, P) mm and finite rows (B,) of `backbones`' states."""
    i_p = 2 + 2 * rod[0].shape[0]
    positions = np.ascontiguousarray(states[:, :, i_p:i_p + 3])
    finite = np.ones(q.shape[0], dtype=np.bool_)
    for b in range(q.shape[0]):
        for v in positions[b].ravel():
            if not math.isfinite(v):
                finite[b] = False
    _, _, radius = _along(q, out_frac, rod[0], outer_radii)
    return positions, radius, finite


@njit(cache=True)
def body_points(q, out_frac, intervals, net, rod, loaded, outer_radii):
    """What a collision check needs, from the network at the nodes the points need only (no tube
    ends, no s = 0): positions (B, P, 3) mm and outer radius (B, P) mm at arc fractions ``out_frac``
    (P,) of l1, and whether each row is finite (B,). Arguments as `backbones`."""
    states = np.empty((q.shape[0], out_frac.shape[0], 2 * rod[0].shape[0] + 9))
    backbones(q, out_frac, intervals, net, rod, loaded, states, states, np.bool_(False))
    return _body_fields(q, out_frac, rod, outer_radii, states)


@njit(cache=True)
def _block(rows, blocks, c):
    """Rows [a, b) of block c of ``rows`` rows split into ``blocks`` contiguous blocks (b <= a: empty)."""
    size = (rows + blocks - 1) // blocks
    return c * size, min(rows, (c + 1) * size)


@njit(cache=True, parallel=True)
def body_points_blocks(q, out_frac, intervals, net, rod, loaded, outer_radii, blocks):
    """`body_points` with the rows split into ``blocks`` contiguous blocks, run in parallel where
    numba has threads. The blocks are fixed, so the result does not depend on the number of threads;
    it agrees with `body_points`' to float32 rounding (BLAS sums a row differently for some batch
    sizes)."""
    nb = q.shape[0]
    states = np.empty((nb, out_frac.shape[0], 2 * rod[0].shape[0] + 9))
    for c in prange(blocks):
        a, b = _block(nb, blocks, c)
        if a < b:
            backbones(q[a:b], out_frac, intervals, net, rod, loaded, states[a:b], states[a:b],
                      np.bool_(False))
    return _body_fields(q, out_frac, rod, outer_radii, states)


@njit(cache=True, parallel=True)
def infer_blocks(q, frac, net, out, blocks):
    """`infer` (``net``: its weights tuple) with the rows split into ``blocks`` contiguous blocks, run
    in parallel where numba has threads; the blocks are fixed, so the result does not depend on the
    number of threads."""
    for c in prange(blocks):
        a, b = _block(q.shape[0], blocks, c)
        if a < b:
            infer(q[a:b], frac[a:b], *net, out[a:b])
