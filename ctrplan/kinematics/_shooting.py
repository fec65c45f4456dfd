"""Numba kernels of the Cosserat-rod shooting solver (paper eq. 9-13). Internal units: mm, N, 1/mm.

State layout (15, paper eq. 9): ``[m_bx, m_by, u1z, u2z, u3z, th1, th2, th3, px, py, pz, qw, qx, qy, qz]``
with ``m_b`` the body-frame bending moment of the tube bundle (N*mm), ``u_iz`` torsional curvature
(1/mm), ``th_i`` twist of tube i relative to tube 1 (rad), ``p`` position (mm), ``q`` orientation of
tube 1 as a scalar-first unit quaternion.

The arc length ``[0, l1]`` is split at every transition point (tube ends, starts of curved parts);
each segment is stepped with fixed RK4 steps no longer than ``h_multi`` where two or more tubes are
curved (torsion is generated there) and ``h_single`` elsewhere. Values between grid nodes come from
cubic Hermite interpolation with one-sided derivatives, so the grid never depends on the requested
output points and the boundary residual of the returned solution is the one Newton drove to zero.

Unknowns of the shooting (scaled to 1/mm): in free space only ``(u2z(0), u3z(0))`` -- the total moment
vanishes everywhere, so ``m_b = 0`` and ``u1z(0) = -(GJ2 u2z + GJ3 u3z)/GJ1``. With loads:
``(m_bx(0)/EI1, m_by(0)/EI1, u1z(0), u2z(0), u3z(0))``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

NSTATE = 15
I_MB, I_UZ, I_TH, I_P, I_Q = 0, 2, 5, 8, 11
MAX_BREAKS = 8


@njit(cache=True)
def segments(beta, lengths, straight, EI):
    """Split ``[0, l1]`` at every transition point (tube ends, starts of curved parts).

    Returns ``breaks`` (S+1,) mm, ``present`` and ``kc`` (S, 3) per segment (tube present; curvature
    if curved else 0, 1/mm), ``bend`` (S,) total bending stiffness, ``ncurved`` (S,) curved tubes.
    """
    ends = beta + lengths
    l1 = ends[0]
    cand = np.empty(MAX_BREAKS)
    n = 0
    cand[n] = 0.0
    n += 1
    for i in range(3):
        cand[n] = ends[i]
        n += 1
        c = beta[i] + straight[i]
        if c > 0.0 and c < l1:
            cand[n] = c
            n += 1
    br = np.sort(cand[:n])
    breaks = np.empty(n)
    nb = 0
    for v in br:
        if v < 0.0 or v > l1:
            continue
        if nb == 0 or v - breaks[nb - 1] > 1e-9:
            breaks[nb] = v
            nb += 1
    nseg = nb - 1
    present = np.zeros((nseg, 3))
    kc = np.zeros((nseg, 3))
    bend = np.zeros(nseg)
    ncurved = np.zeros(nseg, dtype=np.int64)
    for k in range(nseg):
        mid = 0.5 * (breaks[k] + breaks[k + 1])
        for i in range(3):
            if ends[i] > mid:
                present[k, i] = 1.0
                bend[k] += EI[i]
                if beta[i] + straight[i] < mid:
                    ncurved[k] += 1
                    kc[k, i] = 1.0
    return breaks[:nb], present, kc, bend, ncurved


@njit(cache=True)
def lay_nodes(breaks, steps, ends):
    """Nodes ``(M+1,)`` mm with ``steps[k]`` equal intervals on segment k; ``seg_of`` (M,) segment of
    each interval; ``end_node`` (3,) node index nearest to each tube end ``ends`` (3,) mm."""
    nseg = steps.shape[0]
    m = int(steps.sum())
    nodes = np.empty(m + 1)
    seg_of = np.empty(m, dtype=np.int64)
    j = 0
    for k in range(nseg):
        a, b = breaks[k], breaks[k + 1]
        for t in range(steps[k]):
            nodes[j] = a + (b - a) * t / steps[k]
            seg_of[j] = k
            j += 1
    nodes[m] = breaks[nseg]
    end_node = np.zeros(3, dtype=np.int64)
    for i in range(3):
        best = 0
        for jj in range(m + 1):
            if abs(nodes[jj] - ends[i]) < abs(nodes[best] - ends[i]):
                best = jj
        end_node[i] = best
    return nodes, seg_of, end_node


@njit(cache=True)
def build_grid(beta, lengths, straight, EI, h_multi, h_single):
    """Segment the backbone (`segments`) and lay out RK4 nodes.

    Returns ``nodes`` (M+1,) mm, ``seg_of`` (M,) segment index of each interval, ``present`` and
    ``kc`` (S, 3) per segment, ``bend`` (S,), ``end_node`` (3,) node index of each tube end ``l_i``.
    """
    breaks, present, kc, bend, ncurved = segments(beta, lengths, straight, EI)
    nseg = bend.shape[0]
    steps = np.zeros(nseg, dtype=np.int64)
    for k in range(nseg):
        h = h_multi if ncurved[k] >= 2 else h_single
        steps[k] = max(1, int(math.ceil((breaks[k + 1] - breaks[k]) / h - 1e-9)))
    nodes, seg_of, end_node = lay_nodes(breaks, steps, beta + lengths)
    return nodes, seg_of, present, kc, bend, end_node


@njit(cache=True)
def rhs(s, y, pres, kc, kappa, bend, EI, GJ, ends, force, weight, loaded, with_pose, dy):
    """dy/ds of the 15-state on one segment. ``kc`` flags curved tubes; ``weight`` (3, 3) N/mm."""
    c2 = math.cos(y[I_TH + 1])
    s2 = math.sin(y[I_TH + 1])
    c3 = math.cos(y[I_TH + 2])
    s3 = math.sin(y[I_TH + 2])
    k1 = EI[0] * kappa[0] * kc[0]
    k2 = EI[1] * kappa[1] * kc[1]
    k3 = EI[2] * kappa[2] * kc[2]
    ux = (y[I_MB] + k1 + k2 * c2 + k3 * c3) / bend
    uy = (y[I_MB + 1] + k2 * s2 + k3 * s3) / bend
    uz = y[I_UZ]
    # torsion of each tube: u_iz' = (EI_i/GJ_i) kappa_i (sin th_i u1x - cos th_i u1y)
    dy[I_UZ] = pres[0] * k1 / GJ[0] * (-uy)
    dy[I_UZ + 1] = pres[1] * k2 / GJ[1] * (s2 * ux - c2 * uy)
    dy[I_UZ + 2] = pres[2] * k3 / GJ[2] * (s3 * ux - c3 * uy)
    dy[I_TH] = 0.0
    dy[I_TH + 1] = pres[1] * (y[I_UZ + 1] - uz)
    dy[I_TH + 2] = pres[2] * (y[I_UZ + 2] - uz)
    if not with_pose:
        dy[I_MB] = 0.0
        dy[I_MB + 1] = 0.0
        for i in range(I_P, NSTATE):
            dy[i] = 0.0
        return
    qw, qx, qy, qz = y[I_Q], y[I_Q + 1], y[I_Q + 2], y[I_Q + 3]
    # third column of R (tangent) and the rest of R for R^T n
    r02 = 2.0 * (qx * qz + qw * qy)
    r12 = 2.0 * (qy * qz - qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    dy[I_P] = r02
    dy[I_P + 1] = r12
    dy[I_P + 2] = r22
    dy[I_Q] = 0.5 * (-qx * ux - qy * uy - qz * uz)
    dy[I_Q + 1] = 0.5 * (qw * ux + qy * uz - qz * uy)
    dy[I_Q + 2] = 0.5 * (qw * uy + qz * ux - qx * uz)
    dy[I_Q + 3] = 0.5 * (qw * uz + qx * uy - qy * ux)
    if not loaded:
        dy[I_MB] = 0.0
        dy[I_MB + 1] = 0.0
        return
    nx, ny, nz = force[0], force[1], force[2]
    for i in range(3):
        d = ends[i] - s
        if d > 0.0:
            nx += weight[i, 0] * d
            ny += weight[i, 1] * d
            nz += weight[i, 2] * d
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    r01 = 2.0 * (qx * qy - qw * qz)
    r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r21 = 2.0 * (qy * qz + qw * qx)
    nbx = r00 * nx + r10 * ny + r20 * nz
    nby = r01 * nx + r11 * ny + r21 * nz
    mx, my = y[I_MB], y[I_MB + 1]
    mz = pres[0] * GJ[0] * y[I_UZ] + pres[1] * GJ[1] * y[I_UZ + 1] + pres[2] * GJ[2] * y[I_UZ + 2]
    # m_b' = -u x m_b - e3 x R^T n
    dy[I_MB] = -(uy * mz - uz * my) + nby
    dy[I_MB + 1] = -(uz * mx - ux * mz) - nbx


@njit(cache=True)
def initial_state(x, beta, alpha, EI, GJ, loaded, y):
    """State at s = 0 from the shooting unknowns ``x`` (paper eq. 10-12)."""
    for i in range(NSTATE):
        y[i] = 0.0
    if loaded:
        y[I_MB] = x[0] * EI[0]
        y[I_MB + 1] = x[1] * EI[0]
        u1, u2, u3 = x[2], x[3], x[4]
    else:
        u2, u3 = x[0], x[1]
        u1 = -(GJ[1] * u2 + GJ[2] * u3) / GJ[0]
    y[I_UZ] = u1
    y[I_UZ + 1] = u2
    y[I_UZ + 2] = u3
    phi1 = alpha[0] - beta[0] * u1
    y[I_TH + 1] = alpha[1] - beta[1] * u2 - phi1
    y[I_TH + 2] = alpha[2] - beta[2] * u3 - phi1
    y[I_Q] = math.cos(0.5 * phi1)
    y[I_Q + 3] = math.sin(0.5 * phi1)


@njit(cache=True)
def integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, with_pose,
              nodes, seg_of, present, kc, bend, end_node, store, Y, Fl, Fr, y_end):
    """RK4 over the grid. ``y_end`` (3, 15) receives the states at the tube ends ``l_i``.

    With ``store``, ``Y`` (M+1, 15) receives the node states and ``Fl``/``Fr`` (M, 15) the one-sided
    derivatives at the left/right node of every interval (for Hermite output).
    """
    y = np.empty(NSTATE)
    initial_state(x, beta, alpha, EI, GJ, loaded, y)
    k1 = np.empty(NSTATE)
    k2 = np.empty(NSTATE)
    k3 = np.empty(NSTATE)
    k4 = np.empty(NSTATE)
    tmp = np.empty(NSTATE)
    if store:
        Y[0, :] = y
    for i in range(3):
        if end_node[i] == 0:
            y_end[i, :] = y
    m = nodes.shape[0] - 1
    for j in range(m):
        k = seg_of[j]
        pres = present[k]
        kcs = kc[k]
        bd = bend[k]
        s0 = nodes[j]
        h = nodes[j + 1] - s0
        rhs(s0, y, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k1)
        for i in range(NSTATE):
            tmp[i] = y[i] + 0.5 * h * k1[i]
        rhs(s0 + 0.5 * h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k2)
        for i in range(NSTATE):
            tmp[i] = y[i] + 0.5 * h * k2[i]
        rhs(s0 + 0.5 * h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k3)
        for i in range(NSTATE):
            tmp[i] = y[i] + h * k3[i]
        rhs(s0 + h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k4)
        for i in range(NSTATE):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if with_pose:
            nq = math.sqrt(y[I_Q] ** 2 + y[I_Q + 1] ** 2 + y[I_Q + 2] ** 2 + y[I_Q + 3] ** 2)
            for i in range(I_Q, I_Q + 4):
                y[i] /= nq
        if store:
            Y[j + 1, :] = y
            Fl[j, :] = k1
            rhs(s0 + h, y, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, tmp)
            Fr[j, :] = tmp
        for i in range(3):
            if end_node[i] == j + 1:
                y_end[i, :] = y


@njit(cache=True)
def _norm_inf(r):
    v = 0.0
    for i in range(r.shape[0]):
        a = abs(r[i])
        if not a <= v:  # also catches NaN
            v = a if a == a else np.inf
    return v


@njit(cache=True)
def residual_of(y_end, EI, GJ, loaded, r):
    """Distal boundary residual as moments over tube-1 stiffness (1/mm): ``GJ_i u_iz(l_i) / GJ_1``
    and, with loads, ``m_b,xy(l1) / EI_1``. In free space ``u_1z(l_1)`` then vanishes with the others."""
    if loaded:
        r[0] = y_end[0, I_MB] / EI[0]
        r[1] = y_end[0, I_MB + 1] / EI[0]
        r[2] = y_end[0, I_UZ]
        r[3] = y_end[1, I_UZ + 1] * GJ[1] / GJ[0]
        r[4] = y_end[2, I_UZ + 2] * GJ[2] / GJ[0]
    else:
        r[0] = y_end[1, I_UZ + 1] * GJ[1] / GJ[0]
        r[1] = y_end[2, I_UZ + 2] * GJ[2] / GJ[0]


@njit(cache=True)
def full_residual(y_end, EI, GJ):
    """Max over all five distal conditions of the normalised residual of `residual_of`, in 1/m."""
    r = np.empty(5)
    residual_of(y_end, EI, GJ, True, r)
    return _norm_inf(r) * 1e3


@njit(cache=True)
def _evaluate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
              nodes, seg_of, present, kc, bend, end_node, y_end, dummy, r):
    """Residual ``r`` of the unknowns ``x``; returns its max norm (inf if not finite)."""
    integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, loaded,
              nodes, seg_of, present, kc, bend, end_node, False, dummy, dummy, dummy, y_end)
    residual_of(y_end, EI, GJ, loaded, r)
    return _norm_inf(r)


@njit(cache=True)
def shoot(x0, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
          nodes, seg_of, present, kc, bend, end_node, tol, max_iter):
    """Damped quasi-Newton on the shooting unknowns: a finite-difference Jacobian, then Broyden
    rank-one updates (rebuilt by finite differences whenever a step is rejected).

    Returns ``(x, converged, iterations, |r|_inf in 1/mm)``.
    """
    nx = x0.shape[0]
    x = x0.copy()
    dummy = np.empty((1, NSTATE))
    y_end = np.empty((3, NSTATE))
    r = np.empty(nx)
    rt = np.empty(nx)
    J = np.empty((nx, nx))
    args = (beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
            nodes, seg_of, present, kc, bend, end_node, y_end, dummy)
    rn = _evaluate(x, *args, r)
    it = 0
    fresh = False  # is J a finite-difference Jacobian at the current x?
    have_j = False
    while it < max_iter:
        if rn <= tol:
            return x, True, it, rn
        if not have_j:
            for j in range(nx):
                d = 1e-7 * max(abs(x[j]), 1e-3)
                xj = x[j]
                x[j] = xj + d
                _evaluate(x, *args, rt)
                x[j] = xj
                for i in range(nx):
                    J[i, j] = (rt[i] - r[i]) / d
            if not np.all(np.isfinite(J)):
                break
            fresh = True
            have_j = True
        it += 1
        dx = np.linalg.solve(J, -r)
        t = 1.0
        accepted = False
        for _ in range(12):
            xt = x + t * dx
            rtn = _evaluate(xt, *args, rt)
            if rtn < (1.0 - 1e-4 * t) * rn:
                accepted = True
                break
            t *= 0.5
        if not accepted:
            if fresh:
                break
            have_j = False  # Broyden Jacobian went stale: rebuild it by finite differences
            continue
        # Broyden rank-one update with the accepted step
        step = xt - x
        denom = np.dot(step, step)
        if denom > 0.0:
            corr = (rt - r) - J @ step
            for i in range(nx):
                for j in range(nx):
                    J[i, j] += corr[i] * step[j] / denom
        fresh = False
        x = xt
        r[:] = rt
        rn = rtn
    return x, rn <= tol, it, rn


@njit(cache=True)
def hermite(nodes, seg_of, Y, Fl, Fr, s_out, out):
    """Cubic Hermite interpolation of the node states at arc lengths ``s_out`` (ascending)."""
    m = nodes.shape[0] - 1
    j = 0
    for n in range(s_out.shape[0]):
        s = s_out[n]
        while j < m - 1 and s > nodes[j + 1]:
            j += 1
        h = nodes[j + 1] - nodes[j]
        t = (s - nodes[j]) / h
        t = min(max(t, 0.0), 1.0)
        t2 = t * t
        t3 = t2 * t
        h00 = 2 * t3 - 3 * t2 + 1
        h10 = t3 - 2 * t2 + t
        h01 = -2 * t3 + 3 * t2
        h11 = t3 - t2
        for i in range(NSTATE):
            out[n, i] = h00 * Y[j, i] + h10 * h * Fl[j, i] + h01 * Y[j + 1, i] + h11 * h * Fr[j, i]
        nq = math.sqrt(out[n, I_Q] ** 2 + out[n, I_Q + 1] ** 2 + out[n, I_Q + 2] ** 2 + out[n, I_Q + 3] ** 2)
        for i in range(I_Q, I_Q + 4):
            out[n, i] /= nq


@njit(cache=True)
def _solve_loaded_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                       nodes, seg_of, present, kc, bend, end_node, tol, max_iter):
    """Cold start under load: free-space solution first, then continuation in load magnitude.

    This picks the equilibrium branch connected to the unloaded robot (a loaded CTR can have
    several). Returns ``(x, converged, iterations, |r|)``.
    """
    xf, conv, it, rn = shoot(np.zeros(2), beta, alpha, kappa, EI, GJ, ends, force, weight, False,
                             nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
    x_start = np.zeros(5)
    x_start[2] = -(GJ[1] * xf[0] + GJ[2] * xf[1]) / GJ[0]
    x_start[3:] = xf
    if not conv:
        return x_start, False, it, rn
    n = 1
    while n <= 32:
        x = x_start.copy()
        for k in range(1, n + 1):
            lam = k / n
            x, conv, itk, rn = shoot(x, beta, alpha, kappa, EI, GJ, ends, lam * force, lam * weight,
                                     True, nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
            it += itk
            if not conv:
                break
        if conv:
            return x, True, it, rn
        n *= 4
    return x, False, it, rn


@njit(cache=True)
def solve_one(q, x0, warm, s_frac, lengths, straight, kappa, EI, GJ, force, weight, loaded,
              h_multi, h_single, tol, max_iter, states, tips, state0):
    """Solve one configuration. ``x0`` is the warm-start guess, used when ``warm``; otherwise (or if
    the warm start fails) a cold start from zero torsion. ``s_frac`` (N,) are output arc lengths as
    fractions of l1.

    Fills ``states`` (N, 15), ``tips`` (3, 3) and ``state0`` (15,) at s = 0; returns
    ``(x, converged, iterations, residual in 1/m)``. On non-convergence the outputs are NaN.
    """
    beta = q[:3].copy()
    alpha = q[3:].copy()
    ends = beta + lengths
    nodes, seg_of, present, kc, bend, end_node = build_grid(beta, lengths, straight, EI, h_multi, h_single)
    conv = False
    it = 0
    x = x0.copy()
    if warm:
        x, conv, it, rn = shoot(x0, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
                                nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
    if not conv:
        if loaded:
            x, conv, itc, rn = _solve_loaded_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                                                  nodes, seg_of, present, kc, bend, end_node, tol,
                                                  max_iter)
        else:
            x, conv, itc, rn = shoot(np.zeros(2), beta, alpha, kappa, EI, GJ, ends, force, weight,
                                     False, nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
        it += itc
    m = nodes.shape[0] - 1
    Y = np.empty((m + 1, NSTATE))
    Fl = np.empty((m, NSTATE))
    Fr = np.empty((m, NSTATE))
    y_end = np.empty((3, NSTATE))
    integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, True,
              nodes, seg_of, present, kc, bend, end_node, True, Y, Fl, Fr, y_end)
    res = full_residual(y_end, EI, GJ)
    conv = conv and res <= 2.0 * tol * 1e3
    if not conv:
        states[:, :] = np.nan
        tips[:, :] = np.nan
        state0[:] = np.nan
        return x, False, it, res
    state0[:] = Y[0]
    hermite(nodes, seg_of, Y, Fl, Fr, s_frac * ends[0], states)
    for i in range(3):
        for d in range(3):
            tips[i, d] = y_end[i, I_P + d]
    return x, True, it, res


@njit(cache=True, parallel=True)
def solve_many(Q, X0, warm, s_frac, lengths, straight, kappa, EI, GJ, force, weight, loaded,
               h_multi, h_single, tol, max_iter, states, tips, state0, X, conv, iters, resid):
    """`solve_one` over a batch (B, 6) in parallel; outputs indexed by the batch row."""
    for b in prange(Q.shape[0]):
        x, c, it, r = solve_one(Q[b], X0[b], warm, s_frac, lengths, straight, kappa, EI, GJ, force, weight,
                                loaded, h_multi, h_single, tol, max_iter, states[b], tips[b],
                                state0[b])
        X[b, :] = x
        conv[b] = c
        iters[b] = it
        resid[b] = r
