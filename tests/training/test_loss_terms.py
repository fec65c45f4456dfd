"""Training loss terms: which count at a step, from the recipe's weights, cadence and data."""

from __future__ import annotations

from types import SimpleNamespace

from ctrplan.training.recipes import RECIPES, Recipe
from ctrplan.training.terms import LOSS_TERMS, default_weights


def _active(recipe: Recipe, step: int, observations: int = 10) -> list[str]:
    data = SimpleNamespace(obs_q=[0] * observations)
    return [name for name, term in LOSS_TERMS.items() if term.active(recipe, data, step)]


def test_terms_count_by_weight_cadence_and_data():
    fast = RECIPES["fast"]  # physics every 20th step, no tip observations (weight 0)
    assert fast.physics_every == 20 and fast.weights["obs"] == 0.0
    assert _active(fast, 0) == ["ode", "bc", "dense"]
    assert _active(fast, 7) == ["dense"]
    assert _active(fast, 40) == ["ode", "bc", "dense"]
    finetune = RECIPES["finetune"]  # every 4th step; observations weighted
    assert _active(finetune, 4) == ["ode", "bc", "obs", "dense"]
    assert _active(finetune, 5) == ["obs", "dense"]
    assert _active(finetune, 5, observations=0) == ["dense"]  # nothing observed: no term


def test_a_recipe_without_weights_weights_the_paper_terms():
    paper = Recipe(name="x", optimizer="lbfgs", steps=1, lr=1.0)
    assert paper.weights == default_weights() == {"ode": 1.0, "bc": 1.0, "obs": 1.0, "dense": 0.0}
    assert _active(paper, 3) == ["ode", "bc", "obs"]  # dense weight 0, dense_batch 0
