"""The training loss as a sum of small term objects (as DeepXDE's conditions): each `LossTerm` has a
``name`` (its key in `Recipe.weights`), a ``weight`` and a ``cadence`` (every how many steps it is
computed) from the recipe, and its ``value`` at a step. `LOSS_TERMS` registers them once; `Losses`
adds up the active ones. Adding a term: one `LossTerm` subclass in `LOSS_TERMS`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

import torch

from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.training.losses import boundary_residual, observation_residual, ode_residual, supervised_residual
from ctrplan.training.physics import TubeTensors

if TYPE_CHECKING:
    from ctrplan.training.recipes import Recipe
    from ctrplan.training.trainer import TrainingData

#: Weights of the state groups ``m_b, u, theta, p, h`` in the per-group residuals.
GROUP_WEIGHTS = (1.0, 1.0, 1.0, 1.0, 1.0)


class LossTerm(ABC):
    """One term of the training loss. ``physics`` terms are computed every ``physics_every`` steps."""

    name: ClassVar[str]
    #: Its weight in a recipe that does not name it.
    default_weight: ClassVar[float] = 1.0
    physics: ClassVar[bool] = False

    def weight(self, recipe: Recipe) -> float:
        return recipe.weights.get(self.name, 0)

    def cadence(self, recipe: Recipe) -> int:
        """Computed at the steps divisible by this."""
        return max(recipe.physics_every, 1) if self.physics else 1

    def has_data(self, recipe: Recipe, data: TrainingData) -> bool:
        return True

    def active(self, recipe: Recipe, data: TrainingData, step: int) -> bool:
        """Whether the term counts at ``step``: weighted, due, and with data to draw on."""
        return bool(self.weight(recipe)) and step % self.cadence(recipe) == 0 and self.has_data(recipe, data)

    @abstractmethod
    def value(self, losses: Losses, net: PinnNet, step: int) -> torch.Tensor:
        """The unweighted term (a scalar) at ``step``; batches drawn from ``losses.data``."""


class OdeResidual(LossTerm):
    """Paper eq. 15: the Cosserat ODE residual at collocation points (resampled each step, or fixed)."""

    name = "ode"
    physics = True

    def value(self, losses, net, step):
        r, d = losses.recipe, losses.data
        sg, qc = d.fixed_colloc or d.sampler.collocation(r.collocation, d.sampler.generator(step, 1))
        return (losses.group_weights * ode_residual(net, sg, qc, losses.tubes, r.norm)).sum()


class BoundaryResidual(LossTerm):
    """Paper eq. 16: boundary conditions at s = 0 and the tube ends."""

    name = "bc"
    physics = True

    def value(self, losses, net, step):
        r, d = losses.recipe, losses.data
        qb = d.fixed_bc
        if qb is None:
            qb = d.sampler.joints(r.boundary, d.sampler.generator(step, 2))
        return (losses.group_weights * boundary_residual(net, qb, losses.tubes, r.norm)).sum()


class TipObservations(LossTerm):
    """Paper eq. 17: the observed tube tips (exact-model tips, or measured ones when fine-tuning)."""

    name = "obs"

    def has_data(self, recipe, data):
        return bool(len(data.obs_q))

    def value(self, losses, net, step):
        d = losses.data
        return observation_residual(net, d.obs_q, d.obs_tips, losses.tubes, losses.recipe.norm,
                                    d.obs_sensor_offset)


class DenseSupervision(LossTerm):
    """Exact Cosserat states along the backbone: a ``mining.share`` of each batch from the hard
    examples, plus ``tip_rows`` rows at the tip."""

    name = "dense"
    default_weight = 0.0

    def has_data(self, recipe, data):
        return bool(recipe.dense_batch)

    def value(self, losses, net, step):
        r = losses.recipe
        sigma, q, x = self.batch(r, losses.data, losses.data.sampler.generator(step if r.resample else 0, 3))
        per_group = supervised_residual(net, sigma, q, x, r.orientation_weight, r.position_weight)
        return (losses.group_weights * per_group).sum()

    @staticmethod
    def batch(r: Recipe, d: TrainingData, g: torch.Generator
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Arc fractions (R,), joints (R, 2N) and exact states (R, 2N + 9) of one supervised batch: rows of
        the exact pool, then of the hard examples, each at a random point of the grid; then the first
        ``tip_rows`` of them again at the tip. Only the states used are gathered."""
        dev = d.dense_q.device
        n_hard = int(r.mining.share * r.dense_batch) if d.hard is not None and len(d.hard) else 0
        ci = torch.randint(0, d.dense_q.shape[0], (r.dense_batch - n_hard,), generator=g, device=dev)
        sources = [(d.dense_q, d.dense_x, ci)]
        if n_hard:
            sources.append((d.hard.q, d.hard.x, d.hard.draw(n_hard, g)))
        pi = torch.randint(0, d.sigma_grid.shape[0], (r.dense_batch,), generator=g, device=dev)
        points = pi.split([len(i) for _, _, i in sources])
        q = torch.cat([qs[i] for qs, _, i in sources])
        xs = torch.cat([xx[i, p] for (_, xx, i), p in zip(sources, points, strict=True)])
        sigma = d.sigma_grid[pi]
        n_tip = int(r.tip_rows * len(q))
        if n_tip:
            tips = torch.cat([xx[i, -1] for _, xx, i in sources])[:n_tip]
            sigma = torch.cat([sigma, torch.ones(n_tip, device=dev)])
            xs = torch.cat([xs, tips])
            q = torch.cat([q, q[:n_tip]])
        return sigma, q, xs


#: Every loss term by name, in the order they are computed and reported.
LOSS_TERMS: dict[str, LossTerm] = {t.name: t for t in (
    OdeResidual(), BoundaryResidual(), TipObservations(), DenseSupervision())}


def default_weights() -> dict[str, float]:
    """`Recipe.weights` of a recipe that sets none: each term's default weight."""
    return {name: term.default_weight for name, term in LOSS_TERMS.items()}


class Losses:
    """The weighted loss of a recipe: the sum of its active `LOSS_TERMS`.
    ``losses(net, step) -> (total, {term: value})``; step ``k`` always draws the same batches from the
    same data."""

    def __init__(self, recipe: Recipe, data: TrainingData, tubes: TubeTensors):
        self.recipe, self.data, self.tubes = recipe, data, tubes
        self.group_weights = torch.tensor(GROUP_WEIGHTS, device=data.dense_q.device)

    def __call__(self, net: PinnNet, k: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        terms = {name: term.value(self, net, k) for name, term in LOSS_TERMS.items()
                 if term.active(self.recipe, self.data, k)}
        total = sum(LOSS_TERMS[name].weight(self.recipe) * v for name, v in terms.items())
        return total, {name: v.detach() for name, v in terms.items()}
