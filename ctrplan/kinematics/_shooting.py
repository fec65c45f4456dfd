"""Numba kernels of the Cosserat-rod shooting solver (paper eq. 9-13) for N = 1…4 tubes.
Internal units: mm, N, 1/mm.

State layout (2N + 9, paper eq. 9; 15 for three tubes):
``[m_bx, m_by, u_1z … u_Nz, th_1 … th_N, px, py, pz, qw, qx, qy, qz]`` with ``m_b`` the body-frame
bending moment of the tube bundle (N*mm), ``u_iz`` torsional curvature (1/mm), ``th_i`` twist of tube i
relative to tube 1 (rad), ``p`` position (mm), ``q`` orientation of tube 1 as a scalar-first unit
quaternion. `layout(n)` gives the offsets. ``kappa`` is passed as a tuple (see
`ctrplan.kinematics.cosserat.RodArrays.arrays`): the tube count is then a compile-time constant.

The arc length ``[0, l1]`` is split at every transition point (tube ends, starts of curved parts);
each segment is stepped with fixed RK4 steps no longer than ``h_multi`` where two or more tubes are
curved (torsion is generated there) and ``h_single`` elsewhere. Values between grid nodes come from
cubic Hermite interpolation with one-sided derivatives, so the grid never depends on the requested
output points and the boundary residual of the returned solution is the one Newton drove to zero.

Unknowns of the shooting (scaled to 1/mm): in free space only ``(u_2z(0) … u_Nz(0))`` -- the total
moment vanishes everywhere, so ``m_b = 0`` and ``u_1z(0) = -(sum_i>1 GJ_i u_iz)/GJ_1``. With loads:
``(m_bx(0)/EI_1, m_by(0)/EI_1, u_1z(0) … u_Nz(0))``.

Elastic stability (`stability_det`): the equilibrium is stable when no focal point of the Jacobi
(variational) equation lies in ``(0, l1]`` -- the determinant of ``d r(s) / d x`` stays positive along
the arc length, with ``r(s)`` the distal boundary quantities evaluated at ``s`` (Ha, Park & Dupont,
IEEE T-RO 2015). Its value at ``s = l1`` is the shooting Jacobian's determinant.

Over 500 lines because it is one compiled solver: the state layout, the right-hand side, the
integrator, shooting, stability and output interpolation call each other inside numba and share the
layout's offsets; split into modules, each would need the others' internals, and a change in one
would silently stale the others' cached machine code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

I_MB, I_UZ = 0, 2
MAX_TUBES = 4
MAX_BREAKS = 2 * MAX_TUBES + 2


@njit(cache=True)
def layout(n):
    """Offsets of the state blocks for n tubes: ``(n_state, I_TH, I_P, I_Q)``."""
    return 2 * n + 9, 2 + n, 2 + 2 * n, 5 + 2 * n


@njit(cache=True)
def segments(beta, lengths, straight, EI):
    """Split ``[0, l1]`` at every transition point (tube ends, starts of curved parts).

    Returns ``breaks`` (S+1,) mm, ``present`` and ``kc`` (S, N) per segment (tube present; curved),
    ``bend`` (S,) total bending stiffness, ``ncurved`` (S,) curved tubes.
    """
    nt = lengths.shape[0]
    ends = beta + lengths
    l1 = ends[0]
    cand = np.empty(MAX_BREAKS)
    n = 0
    cand[n] = 0.0
    n += 1
    for i in range(nt):
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
    present = np.zeros((nseg, nt))
    kc = np.zeros((nseg, nt))
    bend = np.zeros(nseg)
    ncurved = np.zeros(nseg, dtype=np.int64)
    for k in range(nseg):
        mid = 0.5 * (breaks[k] + breaks[k + 1])
        for i in range(nt):
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
    each interval; ``end_node`` (N,) node index nearest to each tube end ``ends`` (N,) mm."""
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
    end_node = np.zeros(ends.shape[0], dtype=np.int64)
    for i in range(ends.shape[0]):
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
    ``kc`` (S, N) per segment, ``bend`` (S,), ``end_node`` (N,) node index of each tube end ``l_i``.
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
    """dy/ds of the (2N + 9)-state on one segment. ``kc`` flags curved tubes; ``weight`` (N, 3) N/mm."""
    nt = len(kappa)
    i_th = 2 + nt
    i_p = i_th + nt
    i_q = i_p + 3
    # tube 1: th_1 = 0, so its pre-curvature moment is along x and its torsion source is -u_y
    # (cos, sin) of th_i are kept in dy's u_z and theta slots until those are written
    c1 = EI[0] * kappa[0] * kc[0]
    mx_pre = c1
    my_pre = 0.0
    for i in range(1, nt):
        ci = EI[i] * kappa[i] * kc[i]
        if ci != 0.0:
            th = y[i_th + i]
            co = math.cos(th)
            si = math.sin(th)
            dy[I_UZ + i] = co
            dy[i_th + i] = si
            mx_pre += ci * co
            my_pre += ci * si
    ux = (y[I_MB] + mx_pre) / bend
    uy = (y[I_MB + 1] + my_pre) / bend
    uz = y[I_UZ]
    # torsion of each tube: u_iz' = (EI_i/GJ_i) kappa_i (sin th_i u1x - cos th_i u1y)
    dy[I_UZ] = -c1 / GJ[0] * uy
    dy[i_th] = 0.0
    for i in range(1, nt):
        ci = EI[i] * kappa[i] * kc[i]
        if ci != 0.0:
            dy[I_UZ + i] = ci / GJ[i] * (dy[i_th + i] * ux - dy[I_UZ + i] * uy)
        else:
            dy[I_UZ + i] = 0.0
        dy[i_th + i] = pres[i] * (y[I_UZ + i] - uz)
    if not with_pose:
        dy[I_MB] = 0.0
        dy[I_MB + 1] = 0.0
        for i in range(i_p, i_q + 4):
            dy[i] = 0.0
        return
    qw, qx, qy, qz = y[i_q], y[i_q + 1], y[i_q + 2], y[i_q + 3]
    # third column of R (tangent) and the rest of R for R^T n
    dy[i_p] = 2.0 * (qx * qz + qw * qy)
    dy[i_p + 1] = 2.0 * (qy * qz - qw * qx)
    dy[i_p + 2] = 1.0 - 2.0 * (qx * qx + qy * qy)
    dy[i_q] = 0.5 * (-qx * ux - qy * uy - qz * uz)
    dy[i_q + 1] = 0.5 * (qw * ux + qy * uz - qz * uy)
    dy[i_q + 2] = 0.5 * (qw * uy + qz * ux - qx * uz)
    dy[i_q + 3] = 0.5 * (qw * uz + qx * uy - qy * ux)
    if not loaded:
        dy[I_MB] = 0.0
        dy[I_MB + 1] = 0.0
        return
    nx, ny, nz = force[0], force[1], force[2]
    mz = 0.0
    for i in range(nt):
        d = ends[i] - s
        if d > 0.0:
            nx += weight[i, 0] * d
            ny += weight[i, 1] * d
            nz += weight[i, 2] * d
        mz += pres[i] * GJ[i] * y[I_UZ + i]
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    r01 = 2.0 * (qx * qy - qw * qz)
    r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r21 = 2.0 * (qy * qz + qw * qx)
    nbx = r00 * nx + r10 * ny + r20 * nz
    nby = r01 * nx + r11 * ny + r21 * nz
    mx, my = y[I_MB], y[I_MB + 1]
    # m_b' = -u x m_b - e3 x R^T n
    dy[I_MB] = -(uy * mz - uz * my) + nby
    dy[I_MB + 1] = -(uz * mx - ux * mz) - nbx


@njit(cache=True)
def initial_state(x, beta, alpha, EI, GJ, loaded, y):
    """State at s = 0 from the shooting unknowns ``x`` (paper eq. 10-12)."""
    nt = beta.shape[0]
    ns, i_th, i_p, i_q = layout(nt)
    for i in range(ns):
        y[i] = 0.0
    if loaded:
        y[I_MB] = x[0] * EI[0]
        y[I_MB + 1] = x[1] * EI[0]
        for i in range(nt):
            y[I_UZ + i] = x[2 + i]
    else:
        tot = 0.0
        for i in range(1, nt):
            y[I_UZ + i] = x[i - 1]
            tot += GJ[i] * x[i - 1]
        y[I_UZ] = -tot / GJ[0]
    phi1 = alpha[0] - beta[0] * y[I_UZ]
    for i in range(1, nt):
        y[i_th + i] = alpha[i] - beta[i] * y[I_UZ + i] - phi1
    y[i_q] = math.cos(0.5 * phi1)
    y[i_q + 3] = math.sin(0.5 * phi1)


@njit(cache=True)
def _normalise_quaternion(y, i_q):
    """Normalise the quaternion ``y[i_q:i_q + 4]`` in place; NaN where it has diverged (zero,
    infinite or NaN norm), so a diverging trial step is rejected instead of dividing by zero."""
    nq = math.sqrt(y[i_q] ** 2 + y[i_q + 1] ** 2 + y[i_q + 2] ** 2 + y[i_q + 3] ** 2)
    ok = 0.0 < nq < np.inf
    for i in range(i_q, i_q + 4):
        y[i] = y[i] / nq if ok else np.nan


@njit(cache=True)
def integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, with_pose,
              nodes, seg_of, present, kc, bend, end_node, store, Y, Fl, Fr, y_end):
    """RK4 over the grid. ``y_end`` (N, 2N + 9) receives the states at the tube ends ``l_i``.

    With ``store``, ``Y`` (M+1, 2N + 9) receives the node states and ``Fl``/``Fr`` (M, 2N + 9) the
    one-sided derivatives at the left/right node of every interval (for Hermite output).
    """
    nt = len(kappa)
    ns = 2 * nt + 9
    y = np.empty(ns)
    initial_state(x, beta, alpha, EI, GJ, loaded, y)
    k1 = np.empty(ns)
    k2 = np.empty(ns)
    k3 = np.empty(ns)
    k4 = np.empty(ns)
    tmp = np.empty(ns)
    if store:
        Y[0, :] = y
    for i in range(nt):
        if end_node[i] == 0:
            y_end[i, :] = y
    m = nodes.shape[0] - 1
    for j in range(m):
        k = seg_of[j]
        s0 = nodes[j]
        h = nodes[j + 1] - s0
        pres = present[k]
        kcs = kc[k]
        bd = bend[k]
        rhs(s0, y, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k1)
        for i in range(ns):
            tmp[i] = y[i] + 0.5 * h * k1[i]
        rhs(s0 + 0.5 * h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k2)
        for i in range(ns):
            tmp[i] = y[i] + 0.5 * h * k2[i]
        rhs(s0 + 0.5 * h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k3)
        for i in range(ns):
            tmp[i] = y[i] + h * k3[i]
        rhs(s0 + h, tmp, pres, kcs, kappa, bd, EI, GJ, ends, force, weight, loaded, with_pose, k4)
        for i in range(ns):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if with_pose:
            _normalise_quaternion(y, ns - 4)
        if store:
            Y[j + 1, :] = y
            Fl[j, :] = k1
            rhs(s0 + h, y, present[k], kc[k], kappa, bend[k], EI, GJ, ends, force, weight, loaded,
                with_pose, tmp)
            Fr[j, :] = tmp
        for i in range(nt):
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
def boundary_quantities(y_at, EI, GJ, loaded, r):
    """Distal boundary quantities as moments over tube-1 stiffness (1/mm), from the states ``y_at``
    (N, 2N + 9) at which tube i's condition is read (row i): ``GJ_i u_iz / GJ_1`` and, with loads,
    ``m_b,xy / EI_1`` (row 0). In free space ``u_1z`` follows from the others and is left out."""
    nt = GJ.shape[0]
    if loaded:
        r[0] = y_at[0, I_MB] / EI[0]
        r[1] = y_at[0, I_MB + 1] / EI[0]
        for i in range(nt):
            r[2 + i] = y_at[i, I_UZ + i] * GJ[i] / GJ[0]
    else:
        for i in range(1, nt):
            r[i - 1] = y_at[i, I_UZ + i] * GJ[i] / GJ[0]


@njit(cache=True)
def full_residual(y_end, EI, GJ):
    """Max over all N + 2 distal conditions of the normalised residual, in 1/m."""
    r = np.empty(GJ.shape[0] + 2)
    boundary_quantities(y_end, EI, GJ, True, r)
    return _norm_inf(r) * 1e3


@njit(cache=True)
def _evaluate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
              nodes, seg_of, present, kc, bend, end_node, y_end, dummy, r):
    """Residual ``r`` of the unknowns ``x``; returns its max norm (inf if not finite)."""
    integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, loaded,
              nodes, seg_of, present, kc, bend, end_node, False, dummy, dummy, dummy, y_end)
    boundary_quantities(y_end, EI, GJ, loaded, r)
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
    nt = len(kappa)
    dummy = np.empty((1, 2 * nt + 9))
    y_end = np.empty((nt, 2 * nt + 9))
    r = np.empty(nx)
    rt = np.empty(nx)
    J = np.empty((nx, nx))
    args = (beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
            nodes, seg_of, present, kc, bend, end_node, y_end, dummy)
    rn = _evaluate(x, *args, r)
    if nx == 0:
        return x, rn <= tol, 0, rn
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
def stability_det(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
                  nodes, seg_of, present, kc, bend, end_node):
    """Smallest value along ``(0, l1]`` of ``det(d r(s)/d x) / det(d r(0)/d x)``, with ``r(s)`` the
    distal boundary quantities (`boundary_quantities`) read at ``s`` (tube i's at ``min(s, l_i)``).

    Positive: no focal point, the equilibrium is stable; zero or negative: it is not. The Jacobi
    fields come from central differences of the fixed-step integration. 1.0 when there is nothing
    to shoot for (one tube in free space).
    """
    nx = x.shape[0]
    if nx == 0:
        return 1.0
    nt = len(kappa)
    ns = 2 * nt + 9
    m = nodes.shape[0] - 1
    Ys = np.empty((2 * nx, m + 1, ns))
    Fl = np.empty((m, ns))
    y_end = np.empty((nt, ns))
    d = np.empty(nx)
    for c in range(nx):
        d[c] = 1e-6 * max(abs(x[c]), 1e-3)
        for sign in range(2):
            xp = x.copy()
            xp[c] += d[c] if sign == 0 else -d[c]
            integrate(xp, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, loaded,
                      nodes, seg_of, present, kc, bend, end_node, True, Ys[2 * c + sign], Fl, Fl, y_end)
    y_at = np.empty((nt, ns))
    rp = np.empty(nx)
    rm = np.empty(nx)
    M = np.empty((nx, nx))
    det0 = 0.0
    worst = np.inf
    for j in range(m + 1):
        for c in range(nx):
            for sign in range(2):
                for i in range(nt):  # tube i's condition is read at min(s, l_i)
                    y_at[i, :] = Ys[2 * c + sign, min(j, end_node[i])]
                boundary_quantities(y_at, EI, GJ, loaded, rp if sign == 0 else rm)
            for r_ in range(nx):
                M[r_, c] = (rp[r_] - rm[r_]) / (2.0 * d[c])
        det = np.linalg.det(M)
        if j == 0:
            det0 = det
        else:
            v = det / det0
            if not v >= worst:
                worst = v if v == v else -np.inf
    return worst


@njit(cache=True)
def hermite(nodes, seg_of, Y, Fl, Fr, s_out, out):
    """Cubic Hermite interpolation of the node states at arc lengths ``s_out`` (ascending)."""
    m = nodes.shape[0] - 1
    ns = Y.shape[1]
    i_q = ns - 4
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
        for i in range(ns):
            out[n, i] = h00 * Y[j, i] + h10 * h * Fl[j, i] + h01 * Y[j + 1, i] + h11 * h * Fr[j, i]
        _normalise_quaternion(out[n], i_q)


@njit(cache=True)
def _free_to_loaded(xf, GJ):
    """Loaded-problem unknowns (N + 2,) of a free-space solution ``xf`` (N - 1,)."""
    nt = GJ.shape[0]
    x = np.zeros(nt + 2)
    tot = 0.0
    for i in range(1, nt):
        x[2 + i] = xf[i - 1]
        tot += GJ[i] * xf[i - 1]
    x[2] = -tot / GJ[0]
    return x


@njit(cache=True)
def _solve_free_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                     nodes, seg_of, present, kc, bend, end_node, tol, max_iter):
    """Cold start in free space: Newton from zero torsion; where that fails (long transmissions and
    strongly curved overlaps make the first steps leave the region Newton converges in), continuation
    in the relative rotations. With every ``alpha_i = alpha_1`` the curvatures lie in one plane and
    zero torsion is the exact solution; the rotations ``alpha_i - alpha_1`` (wrapped to (-pi, pi])
    are then grown to their values in 4 or 16 steps, each warm-started from the last. In a
    snap-free domain this reaches the one equilibrium; elsewhere it follows the branch connected to
    the aligned robot. Returns ``(x, converged, iterations, |r|)``."""
    nt = len(kappa)
    x, conv, it, rn = shoot(np.zeros(nt - 1), beta, alpha, kappa, EI, GJ, ends, force, weight, False,
                            nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
    if conv or nt == 1:
        return x, conv, it, rn
    rel = np.empty(nt)
    for i in range(nt):
        rel[i] = (alpha[i] - alpha[0] + math.pi) % (2.0 * math.pi) - math.pi
    a = alpha.copy()
    n = 4
    while n <= 16:
        x = np.zeros(nt - 1)
        for k in range(1, n + 1):
            for i in range(1, nt):
                a[i] = alpha[0] + rel[i] * k / n
            x, conv, itk, rn = shoot(x, beta, a, kappa, EI, GJ, ends, force, weight, False,
                                     nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
            it += itk
            if not conv:
                break
        if conv:  # the wrapped rotations differ from alpha by multiples of 2 pi: polish at alpha itself
            x, conv, itk, rn = shoot(x, beta, alpha, kappa, EI, GJ, ends, force, weight, False,
                                     nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
            return x, conv, it + itk, rn
        n *= 4
    return x, False, it, rn


@njit(cache=True)
def _solve_loaded_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                       nodes, seg_of, present, kc, bend, end_node, tol, max_iter):
    """Cold start under load: free-space solution first, then continuation in load magnitude.

    This picks the equilibrium branch connected to the unloaded robot (a loaded CTR can have
    several). Returns ``(x, converged, iterations, |r|)``.
    """
    xf, conv, it, rn = _solve_free_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                                        nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
    x_start = _free_to_loaded(xf, GJ)
    if not conv:
        return x_start, False, it, rn
    n = 1
    x = x_start.copy()
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
def _physical(Y, nodes):
    """A solution is physical when every state is finite and no backbone point lies farther from
    the plate than its arc length (an inextensible rod cannot)."""
    ns = Y.shape[1]
    i_p = ns - 7
    for j in range(Y.shape[0]):
        for i in range(ns):
            if not math.isfinite(Y[j, i]):
                return False
        dist = math.sqrt(Y[j, i_p] ** 2 + Y[j, i_p + 1] ** 2 + Y[j, i_p + 2] ** 2)
        if dist > nodes[j] * (1.0 + 1e-6) + 1e-6:
            return False
    return True


@njit(cache=True)
def solvable(q, lengths, straight, kappa, EI, GJ, force, weight, ends):
    """Whether the kernels can integrate configuration q (2N,) at all: every number finite (joints,
    tube parameters, loads), stiffnesses and lengths positive, tube 1 reaching in front of the plate
    (l1 > 0). Anything else -- a fitter's trial that pulls a tube behind the plate, a NaN -- is a
    configuration without a solution, not an error."""
    for v in q:
        if not math.isfinite(v):
            return False
    for i in range(len(kappa)):
        if not (math.isfinite(kappa[i]) and math.isfinite(straight[i]) and math.isfinite(ends[i])):
            return False
        if not (EI[i] > 0.0 and GJ[i] > 0.0 and lengths[i] > 0.0 and math.isfinite(EI[i] + GJ[i])):
            return False
        for a in range(3):
            if not math.isfinite(weight[i, a]):
                return False
    for a in range(3):
        if not math.isfinite(force[a]):
            return False
    return ends[0] > 0.0


@njit(cache=True)
def solve_one(q, x0, warm, s_frac, lengths, straight, kappa, EI, GJ, force, weight, loaded,
              h_multi, h_single, tol, max_iter, with_stability, retry_cold, states, tips, state0):
    """Solve one configuration q (2N,). ``x0`` is the warm-start guess, used when ``warm``; otherwise
    (or if the warm start fails) a cold start from zero torsion. ``s_frac`` (P,) are output arc
    lengths as fractions of l1.

    ``retry_cold``: when a warm start fails, solve cold (else the row is not converged -- what a fitter
    wants: its warm starts track the solution, and a cold start under load is a continuation, slow).

    Fills ``states`` (P, 2N + 9), ``tips`` (N, 3) and ``state0`` (2N + 9,) at s = 0; returns
    ``(x, converged, iterations, residual in 1/m, stability)`` with ``stability`` from
    `stability_det` (NaN unless ``with_stability``). On non-convergence the outputs are NaN.
    """
    nt = len(kappa)
    beta = q[:nt].copy()
    alpha = q[nt:].copy()
    ends = beta + lengths
    if not solvable(q, lengths, straight, kappa, EI, GJ, force, weight, ends):
        states[:, :] = np.nan
        tips[:, :] = np.nan
        state0[:] = np.nan
        return np.zeros(x0.shape[0]), False, 0, np.nan, np.nan
    for v in x0:
        if not math.isfinite(v):
            warm = False     # a guess without a number in it: start cold
    nodes, seg_of, present, kc, bend, end_node = build_grid(beta, lengths, straight, EI, h_multi, h_single)
    conv = False
    it = 0
    x = x0.copy()
    if warm:
        x, conv, it, rn = shoot(x0, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
                                nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
    if not conv and (retry_cold or not warm):
        if loaded:
            x, conv, itc, rn = _solve_loaded_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                                                  nodes, seg_of, present, kc, bend, end_node, tol,
                                                  max_iter)
        else:
            x, conv, itc, rn = _solve_free_cold(beta, alpha, kappa, EI, GJ, ends, force, weight,
                                                nodes, seg_of, present, kc, bend, end_node, tol, max_iter)
        it += itc
    m = nodes.shape[0] - 1
    ns = 2 * nt + 9
    Y = np.empty((m + 1, ns))
    Fl = np.empty((m, ns))
    Fr = np.empty((m, ns))
    y_end = np.empty((nt, ns))
    integrate(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded, True,
              nodes, seg_of, present, kc, bend, end_node, True, Y, Fl, Fr, y_end)
    res = full_residual(y_end, EI, GJ)
    conv = conv and res <= 2.0 * tol * 1e3 and _physical(Y, nodes)
    if not conv:
        states[:, :] = np.nan
        tips[:, :] = np.nan
        state0[:] = np.nan
        return x, False, it, res, np.nan
    stab = np.nan
    if with_stability:
        stab = stability_det(x, beta, alpha, kappa, EI, GJ, ends, force, weight, loaded,
                             nodes, seg_of, present, kc, bend, end_node)
    state0[:] = Y[0]
    hermite(nodes, seg_of, Y, Fl, Fr, s_frac * ends[0], states)
    i_p = 2 + 2 * nt
    for i in range(nt):
        for d in range(3):
            tips[i, d] = y_end[i, i_p + d]
    return x, True, it, res, stab


@njit(cache=True, parallel=True)
def solve_chains(Q, X0, warm, starts, s_frac, lengths, straight, kappa, EI, GJ, force, weight, loaded,
                 h_multi, h_single, tol, max_iter, with_stability, retry_cold, states, tips, state0, X, conv,
                 iters, resid, stab):
    """`solve_one` over rows (B, 2N) in chains ``starts[c]:starts[c + 1]`` run in parallel: a chain's
    first row starts from ``X0`` (when ``warm``), every later row from the solution of the row before
    it (continuation along a path; cold where that did not converge), extrapolated linearly from the
    two rows before it where both converged. Chains of one row (``starts = 0, 1, …, B``) solve a batch
    of independent rows: the one parallel kernel for both (each one compiles for ~17 s per tube count on
    a first run). ``force`` (B, 3): each row's tip force in the robot frame (a follower force differs
    from row to row); outputs indexed by the row."""
    for c in prange(starts.shape[0] - 1):
        for b in range(starts[c], starts[c + 1]):
            follow = b > starts[c] and conv[b - 1]
            x0 = X[b - 1] if follow else X0[b]
            if follow and b - 1 > starts[c] and conv[b - 2]:
                x0 = 2.0 * X[b - 1] - X[b - 2]    # extrapolated along the path
            x, cv, it, r, st = solve_one(Q[b], x0, follow or warm, s_frac, lengths, straight, kappa, EI,
                                         GJ, force[b], weight, loaded, h_multi, h_single, tol, max_iter,
                                         with_stability, retry_cold, states[b], tips[b], state0[b])
            X[b, :] = x
            conv[b] = cv
            iters[b] = it
            resid[b] = r
            stab[b] = st
