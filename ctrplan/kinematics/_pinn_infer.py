"""Compiled PINN inference (numba + BLAS): the same computation as `PinnNet.forward`, without
per-operation framework overhead. `PinnBackend` uses it; tests assert it agrees with the torch net."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

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
    n = nb * nf
    nin = W0.shape[0]
    z = np.empty((n, nin), dtype=np.float32)
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
        for f in range(nf):
            r = b * nf + f
            z[r, 0] = 2.0 * frac[b, f] - 1.0
            if equivariant:
                for i in range(3):
                    z[r, 1 + i] = box[i]
                z[r, 4] = math.cos(q[b, 4] - q[b, 3])
                z[r, 5] = math.cos(q[b, 5] - q[b, 3])
                z[r, 6] = math.sin(q[b, 4] - q[b, 3])
                z[r, 7] = math.sin(q[b, 5] - q[b, 3])
            else:
                for i in range(6):
                    z[r, 1 + i] = box[i]
    h = z @ W0 + b0
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


@njit(cache=True, parallel=True)
def infer_chunked(q, frac, box_lo, box_hi, length1, scales, loaded, equivariant, W0, b0, Wh, bh, Wo, bo,
                  out, chunk):
    """`infer` over cache-sized chunks of ``chunk`` configurations, chunks in parallel (run it with
    single-threaded BLAS: the parallelism is across chunks)."""
    nb = q.shape[0]
    for c in prange((nb + chunk - 1) // chunk):
        a = c * chunk
        b = min(nb, a + chunk)
        infer(q[a:b], frac[a:b], box_lo, box_hi, length1, scales, loaded, equivariant, W0, b0, Wh, bh,
              Wo, bo, out[a:b])
