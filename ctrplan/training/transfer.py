"""Start a robot's PINN from the nearest model already trained (transfer learning).

A network trained for one robot already knows what every CTR's state does along its arc length and
with its tubes' translations and relative rotations; its inputs are the robot's own normalised box
coordinates and its outputs are scaled by the robot's own state scales, so its hidden layers carry
over to another robot of the same tube count. `nearest_model` looks at the shipped models and the
user's ``models/`` and picks the one whose robot is nearest (`robot_distance`); `Transfer.apply`
copies its layers into a network built for the new robot (its box, lengths and output scales; the
source's frame tube), and `Transfer.recipe` warms the learning rate up and lowers it for a near
source. Issue 40 measured it (docs/benchmarks.md): a random design robot of the skull-base study
halved its tip error at equal steps from `pinn_nominal`; a model of the robot itself continued at the
full rate lost half its accuracy in the first minutes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from safetensors.torch import load_file

from ctrplan.base.errors import InputError
from ctrplan.kinematics.model_file import MODELS_DIR, read_card, shipped_models_dir
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot, robot_from_dict
from ctrplan.training.recipes import Recipe

#: Tube properties compared by `robot_distance`.
TUBE_FIELDS = ("curvature_per_mm", "curved_length_mm", "straight_length_mm", "bending_stiffness_nmm2")
#: Learning-rate warm-up (Adam steps) of a transferred start: Adam's moment estimates settle before
#: full steps change trained layers.
WARMUP_STEPS = 200
#: A source robot this far (`robot_distance`) or farther is learned at the recipe's full rate; a
#: nearer one at a rate scaled down in proportion, to `MIN_RATE` of it for the robot itself (its own
#: model continued: the shipped nominal model's second stage ran at 0.15 of the first's rate).
FULL_RATE_DISTANCE = 0.1
MIN_RATE = 0.15
#: Network fields that must agree for the layers to carry over.
SHAPE_FIELDS = ("features", "harmonics", "absolute_angles", "hidden", "layers", "inputs", "outputs")


def _relative(a: float, b: float) -> float:
    scale = max(abs(a), abs(b))
    return 0.0 if scale == 0 else abs(a - b) / scale


def robot_distance(a: Robot, b: Robot) -> float:
    """How different two robots are: the mean relative difference of their tubes' curvature,
    lengths and bending stiffness and the mean difference of their domain boxes' bounds
    (translations relative to tube 1's length, rotations to 2 pi); 0 for the same robot, inf for
    different tube counts."""
    if a.n_tubes != b.n_tubes:
        return math.inf
    terms = [_relative(getattr(ta, k), getattr(tb, k)) for ta, tb in zip(a.tubes, b.tubes, strict=True)
             for k in TUBE_FIELDS]
    n = a.n_tubes
    scale = [a.lengths_mm[0]] * n + [2 * math.pi] * n
    for bounds in ((a.domain.box_lower, b.domain.box_lower), (a.domain.box_upper, b.domain.box_upper)):
        terms += [abs(x - y) / w for x, y, w in zip(*bounds, scale, strict=True)]
    return float(sum(terms) / len(terms))


def card_robot(card: dict, where: Path) -> Robot:
    """The robot a model card was trained for (`InputError` if the card's robot cannot be read)."""
    return robot_from_dict(card["robot"], str(where))


@dataclass(frozen=True)
class Transfer:
    """A model to start from: its weights file, card and distance to the robot being trained."""

    weights: Path
    card: dict
    distance: float

    @property
    def frame(self) -> int:
        """The source network's frame tube (0-based; kept, so its layers keep their meaning)."""
        return int(self.card.get("network", {}).get("frame_tube", 1)) - 1

    def apply(self, net: PinnNet) -> PinnNet:
        """``net`` (built for the new robot: its box, lengths, scales) with the source's layers."""
        tensors = load_file(str(self.weights))
        state = net.state_dict()
        layers = {k: v for k, v in tensors.items() if k.startswith("mlp.")}
        if any(k not in state or state[k].shape != v.shape for k, v in layers.items()):
            raise InputError(f"{self.weights}: its network does not fit the one being trained "
                             f"(network in its card: {self.card.get('network')})")
        state.update({k: v.to(state[k].dtype) for k, v in layers.items()})
        net.load_state_dict(state)
        return net

    def recipe(self, recipe: Recipe) -> Recipe:
        """``recipe`` for a start from this source: a `WARMUP_STEPS` warm-up and the peak learning rate
        scaled by the distance (`FULL_RATE_DISTANCE`, `MIN_RATE`)."""
        rate = min(1.0, max(MIN_RATE, self.distance / FULL_RATE_DISTANCE))
        return replace(recipe, lr=recipe.lr * rate, warmup_steps=max(recipe.warmup_steps, WARMUP_STEPS))

    def to_json(self) -> dict:
        return {"model": self.weights.stem, "file": str(self.weights), "robot": self.card["robot"]["name"],
                "robot_fingerprint": self.card.get("robot_fingerprint"), "distance": round(self.distance, 4)}


def candidate_models() -> list[Path]:
    """The user's models (``models/``) and the shipped ones, weights files."""
    return [*sorted(MODELS_DIR.glob("*.safetensors")), *sorted(shipped_models_dir().glob("*.safetensors"))]


def shape_of(net: PinnNet) -> dict:
    """The card's network fields `SHAPE_FIELDS` of ``net``."""
    return {"features": net.features_mode, "harmonics": net.harmonics, "absolute_angles": net.absolute_angles,
            "hidden": net.hidden, "layers": net.layers, "inputs": net.n_inputs, "outputs": net.n_states}


def nearest_model(robot: Robot, shape: dict, models: list[Path] | None = None) -> Transfer | None:
    """The model among ``models`` (default `candidate_models`) whose network has ``shape`` (the
    `SHAPE_FIELDS`; checkpoints and fine-tuned models are skipped) and whose robot is nearest to
    ``robot`` (`robot_distance`; among equally near ones the most accurate by its card), or None."""
    best, best_key = None, None
    for weights in candidate_models() if models is None else models:
        try:
            card = read_card(weights)
        except InputError:
            continue
        network = card.get("network", {})
        if any(network.get(k) != v for k, v in shape.items()) or "finetuned_on" in card:
            continue
        try:
            d = robot_distance(robot, card_robot(card, weights.with_suffix(".json")))
        except (InputError, KeyError, TypeError):
            continue
        tip_max = card.get("metrics", {}).get("tip_error_mm", {}).get("tube1", {}).get("max")
        key = (round(d, 6), tip_max if isinstance(tip_max, (int, float)) else math.inf)
        if math.isfinite(d) and (best_key is None or key < best_key):
            best, best_key = Transfer(weights, card, d), key
    return best


def load_transfer(model: str | Path, robot: Robot) -> Transfer:
    """A named model (path or name, see `resolve_model`) as a transfer source for ``robot``."""
    from ctrplan.kinematics.model_file import resolve_model

    weights = resolve_model(model)
    if not weights.exists():
        raise InputError(f"{weights}: model to transfer from not found")
    card = read_card(weights)
    return Transfer(weights, card, robot_distance(robot, card_robot(card, weights.with_suffix(".json"))))

