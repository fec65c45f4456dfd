"""Training recipes: what `ctrplan train --recipe NAME` runs (`Recipe`: optimiser, samples, loss
weights, network shape, mining, time budget), by name in `RECIPES`; ``--set FIELD=VALUE`` overrides
fields (`get_recipe`). The trainer (`ctrplan.training.trainer`) describes what each recipe does."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from ctrplan.base.errors import InputError
from ctrplan.training.mining import Mining
from ctrplan.training.terms import default_weights


@dataclass(frozen=True)
class Recipe:
    """A training recipe. Counts are samples; ``steps`` are optimiser steps (L-BFGS: outer steps);
    ``minutes`` is the default time budget (``--time-limit`` overrides it)."""

    name: str
    optimizer: str                  # "adam" | "lbfgs"
    steps: int
    lr: float
    norm: str = "mse"               # group residual: "l2" (paper) | "mse"
    collocation: int = 20_000       # per step (resampled) or fixed (paper)
    boundary: int = 1_000
    observations: int = 1_000       # tip observations from the Cosserat model
    dense_configs: int = 0          # configurations solved densely for supervision (0 = none)
    dense_points: int = 65
    dense_batch: int = 0            # supervised (config, s) pairs per step
    resample: bool = False
    weights: dict = field(default_factory=default_weights)  # loss term -> weight (`LOSS_TERMS`)
    lr_final: float = 1e-5
    warmup_steps: int = 0           # Adam: linear learning-rate ramp (keeps a trained model's state)
    lbfgs_history: int = 50
    features: str = "equivariant"   # network input encoding, see `PinnNet`
    harmonics: int = 1              # relative-rotation harmonics of the encoding, see `PinnNet`
    frame_tube: int = 0             # the encoding's frame tube (1 = innermost); 0: `frame_tube` picks it
    hidden: int = 100               # network width and depth (the paper's 6 x 100)
    layers: int = 6
    tip_rows: float = 0.0           # extra supervised rows at the tip (s = l1), per dense row
    orientation_weight: float = 1.0  # weight of the quaternion residual in the dense supervision
    position_weight: float = 1.0    # weight of the position residual in the dense supervision
    edge_share: float = 0.0         # share of the exact pool with translations near their limits
    physics_every: int = 1          # compute the ODE / boundary terms every k steps
    mining: Mining | None = None    # hard-example mining (`ctrplan.training.mining`)
    minutes: float | None = None    # default time budget


RECIPES = {
    # measured on the nominal robot, 25 min on one (shared) CPU thread, tube-1 tip error on 2,000
    # unseen configurations: this recipe mean 0.20 / max 1.81 mm; physics terms every 4th step instead
    # of every 20th 0.31 / 2.34 mm (a fifth fewer steps and a worse fit); tip rows 1.0 per dense row on
    # 17 points 0.40 / 2.11 mm (the backbone away from the tip 2.5 x worse). Issue 40 (a random design
    # robot of the skull-base study, from pinn_nominal, 5,000 monitor configurations): half the pool
    # near the joint limits (edge_share 0.5) halved the max at equal steps (5.5 against 10.3 mm at
    # 3,400 steps, p99.9 3.5 both); position_weight 3 changed nothing (p99.9 5.0 / max 15.0 against
    # 4.8 / 15.9 mm at 1,500 steps). Supervised batch 1,024 instead of 4,096: the same error at equal
    # steps (design_3, 600 steps) and 2.7-3x the steps per CPU-second, so in 20 CPU-minutes of one
    # thread design_3 reached p99.9 0.66 / max 1.05 mm against 1.04 / 1.49 (eval-model --n 5000); on a
    # GPU (launch-bound) the batch costs nothing: 8x it lowered p99.9 by 4-10 % at equal steps
    "fast": Recipe(name="fast", optimizer="adam", steps=1_000_000, lr=2e-3, collocation=1024, boundary=256,
                   observations=0, dense_configs=100_000, dense_points=33, dense_batch=1024,
                   resample=True, weights={"ode": 0.05, "bc": 0.05, "obs": 0.0, "dense": 1.0},
                   harmonics=4, tip_rows=0.25, orientation_weight=10.0, physics_every=20,
                   edge_share=0.5, mining=Mining(), minutes=20.0),
    "paper": Recipe(name="paper", optimizer="lbfgs", steps=300_000, lr=1.0, norm="l2", features="paper"),
    # full-batch L-BFGS with tip observations, after another recipe (use with init_from)
    "polish": Recipe(name="polish", optimizer="lbfgs", steps=1000, lr=1.0, collocation=2048, boundary=512,
                     observations=2000, dense_configs=3_000, dense_points=65, dense_batch=8192,
                     weights={"ode": 0.05, "bc": 0.05, "obs": 0.05, "dense": 1.0}),
    # paper stage (b), with init_from and measured observations (`ctrplan.training.finetune`): the tips,
    # plus exact states of the robot's mechanics (dense supervision) and the physics residuals, so
    # the network learns what the physics does not explain and stays a model of a robot
    "finetune": Recipe(name="finetune", optimizer="adam", steps=800, lr=3e-4, collocation=1024,
                       boundary=256, observations=0, warmup_steps=50, dense_configs=20_000, dense_points=33,
                       dense_batch=1024, physics_every=4, orientation_weight=10.0,
                       weights={"ode": 0.05, "bc": 0.05, "obs": 1.0, "dense": 0.1}),
}
DEFAULT_RECIPE = "fast"

#: Adam steps of few-shot fine-tuning's adaptation stage (the default recipe on the extended mechanics
#: a diagnosis found, `ctrplan.training.finetune.adapt`): 4-6 minutes on two cores here. Enough for
#: the adapted network to model the extended robot about as well as the start network models its own
#: (hjhdog1, 500 shots, one run; tube-1 tip mean / p99 mm on 2,000 configurations against the exact
#: model: start 0.161 / 0.371, adapted 20,000 steps 0.163 / 0.409, 9,000 steps 0.272 / 0.668). A step
#: budget, not minutes: a 4-minute limit bought 106 steps on a machine at load 7-11.
ADAPT_STEPS = 20_000


def get_recipe(name: str, /, **overrides) -> Recipe:
    """Recipe ``name`` with fields replaced by ``overrides`` (None values are ignored)."""
    if name not in RECIPES:
        raise InputError(f"recipe: unknown recipe {name!r} (available: {', '.join(RECIPES)})")
    if "name" in overrides:
        raise InputError("overrides: name: a recipe is chosen by its name (--recipe), not overridden")
    unknown = set(overrides) - set(Recipe.__dataclass_fields__)
    if unknown:
        raise InputError(f"overrides: unknown recipe field(s) {', '.join(sorted(unknown))} "
                         f"(fields: {', '.join(Recipe.__dataclass_fields__)})")
    values = {k: v for k, v in overrides.items() if v is not None}
    if values.get("mining") is False:
        values["mining"] = None
    if isinstance(values.get("mining"), dict):
        try:
            values["mining"] = Mining(**{**asdict(RECIPES[name].mining or Mining()), **values["mining"]})
        except (TypeError, ValueError) as exc:
            raise InputError(f"overrides: mining: {exc} (fields: {', '.join(Mining.__dataclass_fields__)})"
                             ) from None
    return replace(RECIPES[name], **values)


def pool_size(recipe: Recipe) -> int:
    """Configurations the exact pool of ``recipe`` solves: the largest of its dense configurations,
    its observations and 2000."""
    return max(recipe.dense_configs, recipe.observations, 2000)
