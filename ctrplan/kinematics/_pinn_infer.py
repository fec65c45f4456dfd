"""Compiled PINN inference (numba + BLAS): the same computation as `PinnNet.forward`, without
per-operation framework overhead, and whole backbones from it. `PinnBackend` uses it; tests assert it
agrees with the torch net.

Backbones come either from the network at every requested point (``intervals = 0``) or from the
network at ``intervals + 1`` nodes only -- every transition point (tube ends, starts of curved parts)
is a node -- joined by cubic Hermite interpolation whose slopes are the Cosserat right-hand side
(`_shooting.rhs`) at the predicted node states ("physics-informed interpolation"; at ``s = 0`` the
position slope is ``e3`` exactly, the boundary condition the network's positions are built with).
Arc-length cost is then per node, not per output point.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ctrplan.kinematics._shooting import hermite, lay_nodes, rhs, segments

NSTATE, I_P = 15, 8

# Rational approximation of tanh used by Eigen for float32 (accurate to float32 rounding on the
# clamped range); unlike libm's tanh it vectorises.
_CLAMP = 7.90531110763549805
_A = (4.89352455891786e-03, 6.37261928875436e-04, 1.48572235717979e-05, 5.12229709037114e-08,
      -8.60467152213735e-11, 2.00018790482477e-13, -2.76076847742355e-16)
_B = (4.89352518554385e-03, 2.26843463243900e-03, 1.18534705686654e-04, 1.19825839466702e-06)


@njit(cache=True, fastmath=True)
def _tanh_inplace(a):
    flat = a.reshape(-1)
    for i in range(flat.size):
        x = min(max(flat[i], -_CLAMP), _CLAMP)
        x2 = x * x
        p = ((((((_A[6] * x2 + _A[5]) * x2 + _A[4]) * x2 + _A[3]) * x2 + _A[2]) * x2 + _A[1]) * x2
             + _A[0]) * x
        r = ((_B[3] * x2 + _B[2]) * x2 + _B[1]) * x2 + _B[0]
        flat[i] = p / r


@njit(cache=True, fastmath=True)
def infer(q, frac, box_lo, box_hi, length1, scales, loaded, equivariant, W0, b0, Wh, bh, Wo, bo, out):
    """States ``out`` (B, F, 15) at arc fractions ``frac`` (B, F) for joints ``q`` (B, 6).

    Weights are float32 and laid out for ``x @ W`` (in, out). ``equivariant`` selects the input
    encoding (see `ctrplan.kinematics.pinn`).
    """
    nb, nf = frac.shape
    nin = W0.shape[0]
    # the first layer splits into an arc-length column and a per-configuration part: one row each
    zq = np.empty((nb, nin - 1), dtype=np.float32)
    box = np.empty(6)
    x = np.empty(15)
    for b in range(nb):
        box[0] = q[b, 2]
        box[1] = q[b, 2] - q[b, 1]
        box[2] = q[b, 1] - q[b, 0]
        box[3] = q[b, 3]
        box[4] = q[b, 4]
        box[5] = q[b, 5]
        for i in range(6):
            box[i] = 2.0 * (box[i] - box_lo[i]) / (box_hi[i] - box_lo[i]) - 1.0
        if equivariant:
            for i in range(3):
                zq[b, i] = box[i]
            zq[b, 3] = math.cos(q[b, 4] - q[b, 3])
            zq[b, 4] = math.cos(q[b, 5] - q[b, 3])
            zq[b, 5] = math.sin(q[b, 4] - q[b, 3])
            zq[b, 6] = math.sin(q[b, 5] - q[b, 3])
        else:
            for i in range(6):
                zq[b, i] = box[i]
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
    raw = h @ Wo + bo
    for b in range(nb):
        l1 = q[b, 0] + length1
        a1 = q[b, 3]
        ca, sa = math.cos(a1), math.sin(a1)
        ch, sh = math.cos(0.5 * a1), math.sin(0.5 * a1)
        for f in range(nf):
            r = b * nf + f
            o = out[b, f]
            for i in range(15):
                x[i] = raw[r, i] * scales[i]
            s = frac[b, f] * l1
            o[0] = x[0] * loaded
            o[1] = x[1] * loaded
            o[2], o[3], o[4] = x[2], x[3], x[4]
            o[5], o[6], o[7] = 0.0, x[6], x[7]
            px = s * s / 100.0 * x[8]
            py = s * s / 100.0 * x[9]
            pz = s + s * s / 100.0 * x[10]
            nq = math.sqrt(x[11] ** 2 + x[12] ** 2 + x[13] ** 2 + x[14] ** 2)
            nq = max(nq, 1e-12)
            w, hx, hy, hz = x[11] / nq, x[12] / nq, x[13] / nq, x[14] / nq
            if equivariant:
                o[6] += q[b, 4] - a1
                o[7] += q[b, 5] - a1
                px, py = ca * px - sa * py, sa * px + ca * py
                w, hx, hy, hz = ch * w - sh * hz, ch * hx - sh * hy, ch * hy + sh * hx, ch * hz + sh * w
            o[8], o[9], o[10] = px, py, pz
            o[11], o[12], o[13], o[14] = w, hx, hy, hz


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
    """Network nodes of one configuration q (6,): ``nodes`` (intervals+1,) mm, ``seg_of`` (intervals,),
    per-segment ``present``, ``kc``, ``bend`` (see `_shooting.segments`) and ``end_node`` (3,)."""
    beta = q[:3].copy()
    breaks, present, kc, bend, _ = segments(beta, lengths, straight, EI)
    nodes, seg_of, end_node = lay_nodes(breaks, node_steps(breaks, intervals), beta + lengths)
    return nodes, seg_of, present, kc, bend, end_node


@njit(cache=True)
def backbones(q, out_frac, intervals, net, rod, loaded, states, at_ends):
    """States ``states`` (B, N, 15) at arc fractions ``out_frac`` (N,) of l1 for joints q (B, 6), and
    the network's states ``at_ends`` (B, 4, 15) at the tube ends l1, l2, l3 and at s = 0.

    ``intervals = 0``: the network at every point; otherwise Hermite interpolation between the
    network at ``intervals + 1`` nodes (see the module docstring). ``net`` is the weights tuple of
    `infer`, ``rod`` the arrays ``(lengths, straight, kappa, EI, GJ, force, weight)`` of
    `cosserat.RodArrays`, ``loaded`` whether the robot carries loads.
    """
    lengths, straight, kappa, EI, GJ, force, weight = rod
    nb, n = q.shape[0], out_frac.shape[0]
    if intervals == 0:
        frac = np.empty((nb, n + 4))
        for b in range(nb):
            frac[b, :n] = out_frac
            for i in range(3):
                frac[b, n + i] = (q[b, i] + lengths[i]) / (q[b, 0] + lengths[0])
            frac[b, n + 3] = 0.0
        y = np.empty((nb, n + 4, NSTATE))
        infer(q, frac, *net, y)
        states[:] = y[:, :n]
        at_ends[:] = y[:, n:]
        return
    frac = np.empty((nb, intervals + 1))
    for b in range(nb):
        nodes = node_layout(q[b], intervals, lengths, straight, EI)[0]
        frac[b] = nodes / nodes[-1]
    y = np.empty((nb, intervals + 1, NSTATE))
    infer(q, frac, *net, y)
    fl = np.empty((intervals, NSTATE))
    fr = np.empty((intervals, NSTATE))
    for b in range(nb):  # the layout again: cheaper than keeping ragged per-segment tables
        nodes, seg_of, present, kc, bend, end_node = node_layout(q[b], intervals, lengths, straight, EI)
        ends = q[b, :3] + lengths
        yb = y[b]
        for j in range(intervals):
            k = seg_of[j]
            rhs(nodes[j], yb[j], present[k], kc[k], kappa, bend[k], EI, GJ, ends, force, weight, loaded,
                True, fl[j])
            rhs(nodes[j + 1], yb[j + 1], present[k], kc[k], kappa, bend[k], EI, GJ, ends, force, weight,
                loaded, True, fr[j])
        fl[0, I_P] = 0.0
        fl[0, I_P + 1] = 0.0
        fl[0, I_P + 2] = 1.0
        hermite(nodes, seg_of, yb, fl, fr, out_frac * nodes[-1], states[b])
        for i in range(3):
            at_ends[b, i] = yb[end_node[i]]
        at_ends[b, 3] = yb[0]


@njit(cache=True, parallel=True)
def backbones_chunked(q, out_frac, intervals, net, rod, loaded, states, at_ends, chunk):
    """`backbones` over cache-sized chunks of ``chunk`` configurations, chunks in parallel (run it
    with single-threaded BLAS: the parallelism is across chunks)."""
    nb = q.shape[0]
    for c in prange((nb + chunk - 1) // chunk):
        a = c * chunk
        b = min(nb, a + chunk)
        backbones(q[a:b], out_frac, intervals, net, rod, loaded, states[a:b], at_ends[a:b])
