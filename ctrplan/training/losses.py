"""PINN loss terms (paper eq. 15-17) plus dense supervision. Each returns a per-group tensor (5,)
over the state groups ``m_b, u, theta, p, h``; residuals are divided by the state scales so all
groups are O(1) before the per-group weights are applied. N = 1…4 tubes: states are (2N + 9)."""

from __future__ import annotations

import torch

from ctrplan.kinematics.pinn_net import P_REF_MM, PinnNet
from ctrplan.training.physics import TubeTensors, initial_theta_and_quat, quat_to_matrix, rhs


def groups(n_tubes: int) -> dict[str, slice]:
    """State groups ``m_b, u, theta, p, h`` of the (2N + 9)-state: their slices."""
    n = n_tubes
    return {"m_b": slice(0, 2), "u": slice(2, 2 + n), "theta": slice(2 + n, 2 + 2 * n),
            "p": slice(2 + 2 * n, 5 + 2 * n), "h": slice(5 + 2 * n, 9 + 2 * n)}


def group_norms(e: torch.Tensor, norm: str) -> torch.Tensor:
    """Mean over samples of each group's residual e (B, 2N + 9): ``l2`` = ||e_g|| (paper),
    ``mse`` = ||e_g||^2. Returns (5,)."""
    out = []
    for sl in groups((e.shape[1] - 9) // 2).values():
        sq = (e[:, sl] ** 2).sum(-1)
        out.append((sq + 1e-30).sqrt().mean() if norm == "l2" else sq.mean())
    return torch.stack(out)


def ode_residual(net: PinnNet, sigma: torch.Tensor, q: torch.Tensor, tt: TubeTensors,
                 norm: str = "mse") -> torch.Tensor:
    """Residual of dx/ds = N(x, s, q) at collocation points sigma (B,), q (B, 2N); d/ds of all
    outputs by one jvp."""
    ip = 2 * tt.n_tubes + 2
    l1 = q[:, 0] + tt.lengths[0]
    x, dx_dsigma = torch.func.jvp(lambda sg: net(sg, q), (sigma,), (torch.ones_like(sigma),))
    dxds = dx_dsigma / l1[:, None]
    tip_rotation = None
    if tt.has_follower:    # the follower force turns with the network's own tip frame (held fixed here)
        with torch.no_grad():
            tip_rotation = quat_to_matrix(net(torch.ones_like(sigma), q)[:, -4:])
    r = dxds - rhs(x, sigma * l1, q, tt, tip_rotation)
    e = torch.cat([r[:, :ip] * (P_REF_MM / net.scales[:ip]),
                   r[:, ip:ip + 3] * 100.0,                   # tangent error, percent
                   r[:, ip + 3:] * P_REF_MM], -1)
    return group_norms(e, norm)


def boundary_residual(net: PinnNet, q: torch.Tensor, tt: TubeTensors, norm: str = "mse") -> torch.Tensor:
    """Paper eq. 16 at s = 0 and the tube ends: m_b(l1) = 0, u_iz(l_i) = 0, theta/p/h at s = 0;
    q (B, 2N)."""
    b, n = q.shape[0], tt.n_tubes
    ip = 2 * n + 2
    ends = q[:, :n] + tt.lengths
    sig = torch.cat([torch.zeros(b, device=q.device, dtype=q.dtype),
                     *(ends[:, i] / ends[:, 0] for i in range(n - 1, 0, -1)),
                     torch.ones(b, device=q.device, dtype=q.dtype)])
    x = net(sig, q.repeat(n + 1, 1)).view(n + 1, b, -1)
    x0, at_end = x[0], x[1:].flip(0)            # at_end[i]: states at l_{i+1}
    theta0, h0 = initial_theta_and_quat(x0[:, 2:2 + n], q, tt)
    e = torch.cat([
        at_end[0][:, 0:2],
        torch.stack([at_end[i][:, 2 + i] for i in range(n)], -1),
        x0[:, 2 + n:ip] - theta0,
        x0[:, ip:ip + 3],
        x0[:, ip + 3:] - h0,
    ], -1) / net.scales
    return group_norms(e, norm)


def tube_end_states(net: PinnNet, q: torch.Tensor, tt: TubeTensors) -> torch.Tensor:
    """Predicted states (B, N, 2N + 9) at s = l1 … lN (the tube ends) for joints q (B, 2N)."""
    b, n = q.shape[0], tt.n_tubes
    ends = q[:, :n] + tt.lengths
    sig = (ends / ends[:, :1]).T.reshape(-1)
    return net(sig, q.repeat(n, 1)).view(n, b, -1).transpose(0, 1)


def tracked_tips(net: PinnNet, q: torch.Tensor, tt: TubeTensors,
                 sensor_offset_mm: torch.Tensor | None = None) -> torch.Tensor:
    """Predicted tips of tubes 1…N (B, N, 3) mm, p at s = l1 … lN for joints q (B, 2N), with tube 1's
    tracked point moved by ``sensor_offset_mm`` (3,), a vector fixed in its tip frame (what a sensor on
    the tip sees)."""
    ip = 2 * tt.n_tubes + 2
    states = tube_end_states(net, q, tt)
    tips = states[..., ip:ip + 3]
    if sensor_offset_mm is None:
        return tips
    moved = tips[:, 0] + quat_to_matrix(states[:, 0, ip + 3:]) @ sensor_offset_mm
    return torch.cat([moved[:, None], tips[:, 1:]], 1)


def observation_residual(net: PinnNet, q: torch.Tensor, tips: torch.Tensor, tt: TubeTensors,
                         norm: str = "mse", sensor_offset_mm: torch.Tensor | None = None) -> torch.Tensor:
    """Paper eq. 17: tube-tip positions (B, N, 3) mm at s = l1 … lN (tube 1's at its tracked point,
    see `tracked_tips`); NaN marks a tip that was not measured (left out). Returns a scalar (in mm^2
    for ``mse``)."""
    seen = torch.isfinite(tips).all(-1)
    sq = ((tracked_tips(net, q, tt, sensor_offset_mm) - tips.nan_to_num()) ** 2).sum(-1)[seen]
    return (sq + 1e-30).sqrt().mean() if norm == "l2" else sq.mean()


def supervised_residual(net: PinnNet, sigma: torch.Tensor, q: torch.Tensor, x_true: torch.Tensor,
                        orientation_weight: float = 1.0, position_weight: float = 1.0) -> torch.Tensor:
    """Dense supervision from exact Cosserat states x_true (B, 2N + 9), per group, mean squared and
    scaled; the quaternion and position residuals are multiplied by ``orientation_weight`` and
    ``position_weight``."""
    ip = x_true.shape[1] - 7
    x = net(sigma, q)
    e = (x - x_true) / net.scales
    s = (sigma * (q[:, 0] + net.lengths[0]))[:, None]
    # positions as the evaluation sees them: error over arc length, in percent (5 mm softening at s=0)
    e[:, ip:ip + 3] = (x[:, ip:ip + 3] - x_true[:, ip:ip + 3]) * (100.0 * position_weight) / (s + 5.0)
    e[:, ip + 3:] = e[:, ip + 3:] * orientation_weight
    return group_norms(e, "mse")
