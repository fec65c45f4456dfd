"""PINN loss terms (paper eq. 15-17) plus dense supervision. Each returns a per-group tensor (5,)
over the state groups ``m_b, u, theta, p, h``; residuals are divided by the state scales so all
groups are O(1) before the per-group weights are applied."""

from __future__ import annotations

import torch

from ctrplan.kinematics.pinn import P_REF_MM, PinnNet
from ctrplan.training.physics import TubeTensors, initial_theta_and_quat, rhs

GROUPS = {"m_b": slice(0, 2), "u": slice(2, 5), "theta": slice(5, 8), "p": slice(8, 11),
          "h": slice(11, 15)}


def group_norms(e: torch.Tensor, norm: str) -> torch.Tensor:
    """Mean over samples of each group's residual: ``l2`` = ||e_g|| (paper), ``mse`` = ||e_g||^2."""
    out = []
    for sl in GROUPS.values():
        sq = (e[:, sl] ** 2).sum(-1)
        out.append((sq + 1e-30).sqrt().mean() if norm == "l2" else sq.mean())
    return torch.stack(out)


def ode_residual(net: PinnNet, sigma: torch.Tensor, q: torch.Tensor, tt: TubeTensors,
                 norm: str = "mse") -> torch.Tensor:
    """Residual of dx/ds = N(x, s, q) at collocation points; d/ds of all 15 outputs by one jvp."""
    l1 = q[:, 0] + tt.lengths[0]
    x, dx_dsigma = torch.func.jvp(lambda sg: net(sg, q), (sigma,), (torch.ones_like(sigma),))
    dxds = dx_dsigma / l1[:, None]
    r = dxds - rhs(x, sigma * l1, q, tt)
    e = torch.cat([r[:, :8] * (P_REF_MM / net.scales[:8]),
                   r[:, 8:11] * 100.0,                        # tangent error, percent
                   r[:, 11:] * P_REF_MM], -1)
    return group_norms(e, norm)


def boundary_residual(net: PinnNet, q: torch.Tensor, tt: TubeTensors, norm: str = "mse") -> torch.Tensor:
    """Paper eq. 16 at s = {0, l3, l2, l1}: m_b(l1) = 0, u_iz(l_i) = 0, theta/p/h at s = 0."""
    b = q.shape[0]
    ends = q[:, :3] + tt.lengths
    sig = torch.cat([torch.zeros(b, device=q.device, dtype=q.dtype), ends[:, 2] / ends[:, 0],
                     ends[:, 1] / ends[:, 0], torch.ones(b, device=q.device, dtype=q.dtype)])
    x = net(sig, q.repeat(4, 1)).view(4, b, 15)
    x0, x3, x2, x1 = x[0], x[1], x[2], x[3]
    theta0, h0 = initial_theta_and_quat(x0[:, 2:5], q)
    e = torch.cat([
        x1[:, 0:2],
        torch.stack([x1[:, 2], x2[:, 3], x3[:, 4]], -1),
        x0[:, 5:8] - theta0,
        x0[:, 8:11],
        x0[:, 11:15] - h0,
    ], -1) / net.scales
    return group_norms(e, norm)


def tube_tips(net: PinnNet, q: torch.Tensor, tt: TubeTensors) -> torch.Tensor:
    """Predicted tips of tubes 1..3 (B, 3, 3) mm, i.e. p at s = l1, l2, l3, for joints q (B, 6)."""
    b = q.shape[0]
    ends = q[:, :3] + tt.lengths
    sig = (ends / ends[:, :1]).T.reshape(-1)
    return net(sig, q.repeat(3, 1))[:, 8:11].view(3, b, 3).transpose(0, 1)


def observation_residual(net: PinnNet, q: torch.Tensor, tips: torch.Tensor, tt: TubeTensors,
                         norm: str = "mse") -> torch.Tensor:
    """Paper eq. 17: tube-tip positions (B, 3, 3) mm at s = l1, l2, l3; NaN marks a tip that was not
    measured (left out). Returns a scalar (in mm^2 for ``mse``)."""
    seen = torch.isfinite(tips).all(-1)
    sq = ((tube_tips(net, q, tt) - tips.nan_to_num()) ** 2).sum(-1)[seen]
    return (sq + 1e-30).sqrt().mean() if norm == "l2" else sq.mean()


def supervised_residual(net: PinnNet, sigma: torch.Tensor, q: torch.Tensor, x_true: torch.Tensor
                        ) -> torch.Tensor:
    """Dense supervision from exact Cosserat states (B, 15), per group, mean squared and scaled."""
    x = net(sigma, q)
    e = (x - x_true) / net.scales
    s = (sigma * (q[:, 0] + net.lengths[0]))[:, None]
    # positions as the evaluation sees them: error over arc length, in percent (5 mm softening at s=0)
    e[:, 8:11] = (x[:, 8:11] - x_true[:, 8:11]) * 100.0 / (s + 5.0)
    return group_norms(e, "mse")
