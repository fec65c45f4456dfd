"""PINN model files: weights in safetensors (no pickle) plus a JSON model card.

The card records the robot the model was trained for (its parameters and fingerprint), the network
size, the training recipe, sample counts, wall time, hardware and metrics, and the SHA-256 of the
weights file. Loading refuses a model trained for another robot or whose weights do not match the card.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from importlib import resources
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save

from ctrplan.base.dataio import atomic_write, plain
from ctrplan.base.errors import InputError
from ctrplan.kinematics.pinn_net import FEATURES, PinnNet
from ctrplan.model.robot import Robot

#: Users' own models (`ctrplan train` writes here), relative to the working directory.
MODELS_DIR = Path("models")
DEFAULT_MODEL = "pinn_nominal"
CARD_FORMAT = "ctrplan-pinn/1"


def shipped_models_dir() -> Path:
    """The models shipped inside the package (``ctrplan/data/models``; also in an installed wheel)."""
    return Path(str(resources.files("ctrplan.data").joinpath("models")))


def shipped_models() -> list[str]:
    """Names of the shipped models."""
    return sorted(p.stem for p in shipped_models_dir().glob("*.safetensors"))


def resolve_model(model: str | Path | None) -> Path:
    """Path of a model's ``.safetensors`` from a path (with or without suffix) or a name, looked up
    in ``models/`` (users' models) and then among the shipped models; default `DEFAULT_MODEL`.

    A name found nowhere resolves to ``models/NAME.safetensors`` (which does not exist).
    """
    path = Path(DEFAULT_MODEL if model is None else model)
    if path.suffix in (".safetensors", ".json"):
        path = path.with_suffix("")
    weights = path.with_suffix(".safetensors")
    if path.parent.parts or weights.exists():
        return weights
    for folder in (MODELS_DIR, shipped_models_dir()):
        if (folder / weights).exists():
            return folder / weights
    return MODELS_DIR / weights


def default_model_for(robot: Robot) -> Path:
    """The PINN used when none is named: `DEFAULT_MODEL` if it was trained for ``robot``, else the
    first model in ``models/`` or among the shipped ones whose card carries this robot's fingerprint.
    `InputError` when none does, saying where it looked and how to train one."""
    candidates = [resolve_model(None), *sorted(MODELS_DIR.glob("*.safetensors")),
                  *sorted(shipped_models_dir().glob("*.safetensors"))]
    for weights in candidates:
        try:
            if weights.exists() and read_card(weights).get("robot_fingerprint") == robot.fingerprint:
                return weights
        except InputError:  # an unreadable card elsewhere does not stop the search
            continue
    raise InputError(f"no PINN model trained for robot {robot.name!r} (fingerprint "
                     f"{robot.fingerprint[:12]}; the robot comes from --robot or the scene's `robot:` "
                     f"key) in {MODELS_DIR.resolve()} or among the shipped models "
                     f"({', '.join(shipped_models())}); train one with `ctrplan train --robot ROBOT.yaml "
                     f"--name {robot.name}_pinn`, or use the exact model (--backend cosserat)")


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_model(net: PinnNet, robot: Robot, path: str | Path, card: dict[str, Any]) -> Path:
    """Write ``<path>.safetensors`` and ``<path>.json`` (card completed with robot, network, hash)."""
    weights = Path(path).with_suffix(".safetensors")
    weights.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().cpu().contiguous().float() for k, v in net.state_dict().items()}
    with atomic_write(weights, "wb") as fh:
        fh.write(save(tensors))
    full = {
        "format": CARD_FORMAT,
        "robot": robot.to_dict(),
        "robot_fingerprint": robot.fingerprint,
        "network": {"inputs": net.n_inputs, "features": net.features_mode, "harmonics": net.harmonics,
                    "absolute_angles": net.absolute_angles, "frame_tube": net.frame + 1, "hidden": net.hidden,
                    "layers": net.layers, "outputs": net.n_states, "activation": "tanh"},
        **card,
        "weights_file": weights.name,
        "weights_sha256": file_sha256(weights),
    }
    with atomic_write(weights.with_suffix(".json")) as fh:
        fh.write(json.dumps(plain(full), indent=2))
    return weights


def read_card(weights: Path) -> dict[str, Any]:
    card_path = weights.with_suffix(".json")
    try:
        card = json.loads(card_path.read_text())
    except FileNotFoundError:
        raise InputError(f"{card_path}: model card not found (every model needs its JSON card)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{card_path}: unreadable model card ({exc})") from None
    if not isinstance(card, dict) or card.get("format") != CARD_FORMAT:
        raise InputError(f"{card_path}: not a ctrplan PINN model card (format {CARD_FORMAT!r} expected)")
    return card


def write_card_field(weights: Path, key: str, value: Any) -> None:
    """Set one top-level field of a model's card (atomically); the weights and their hash stay."""
    card = read_card(weights)
    card[key] = value
    with atomic_write(weights.with_suffix(".json")) as fh:
        fh.write(json.dumps(plain(card), indent=2))


def load_model(model: str | Path | None, robot: Robot) -> tuple[PinnNet, dict[str, Any]]:
    """Load and verify a model for ``robot`` (``model=None``: `default_model_for` the robot);
    `InputError` naming the file on any mismatch."""
    weights = resolve_model(model) if model is not None else default_model_for(robot)
    if not weights.exists():
        raise InputError(f"{weights}: PINN model not found (shipped models: {', '.join(shipped_models())}; "
                         "train one with `ctrplan train`)")
    card = read_card(weights)
    if card.get("robot_fingerprint") != robot.fingerprint:
        trained_for = card.get("robot", {}).get("name", "?")
        own = weights.with_name(f"{weights.stem}.robot.yaml")
        if own.is_file():  # a fine-tuned model carries the robot it was fitted to
            raise InputError(
                f"{weights}: model was trained for robot {trained_for!r}, not for robot {robot.name!r} "
                f"(fingerprint {robot.fingerprint[:12]}); its robot file is {own}: pass it with "
                f"`--robot {own}` (fk, shape, plan) or name it in the scene's `robot:` key")
        raise InputError(
            f"{weights}: model was trained for robot {trained_for!r} "
            f"(fingerprint {str(card.get('robot_fingerprint'))[:12]}), not for robot {robot.name!r} "
            f"(fingerprint {robot.fingerprint[:12]}; the robot comes from --robot or the scene's "
            f"`robot:` key); train one for it with `ctrplan train --robot ROBOT.yaml --name "
            f"{robot.name}_pinn` and use `--model {robot.name}_pinn` (with measured tips, then "
            f"`ctrplan train --robot ROBOT.yaml --init {robot.name}_pinn --measured DATA.csv --shots 500`)")
    if file_sha256(weights) != card.get("weights_sha256"):
        raise InputError(f"{weights}: weights do not match the SHA-256 in the model card "
                         "(file modified or corrupted)")
    try:
        tensors = load_file(str(weights))
    except (SafetensorError, OSError, ValueError) as exc:
        raise InputError(f"{weights}: corrupted weights file ({exc})") from None
    netcfg = card.get("network", {})
    features = netcfg.get("features", "paper")
    if features not in FEATURES:
        raise InputError(f"{weights.with_suffix('.json')}: unknown network features {features!r}")
    try:
        net = PinnNet(robot, hidden=int(netcfg.get("hidden", 100)), layers=int(netcfg.get("layers", 6)),
                      features=features, harmonics=int(netcfg.get("harmonics", 1)),
                      absolute_angles=bool(netcfg.get("absolute_angles", False)),
                      frame=int(netcfg.get("frame_tube", 1)) - 1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{weights.with_suffix('.json')}: network section unusable ({exc})") from None
    try:
        net.load_state_dict(tensors)
    except RuntimeError as exc:
        raise InputError(f"{weights}: weights do not fit the network in the card ({exc})") from None
    if not all(torch.isfinite(v).all() for v in tensors.values()):
        raise InputError(f"{weights}: weights contain NaN or inf")
    if card.get("meets_target") is False:
        warnings.warn(below_target(weights, card), stacklevel=2)
    return net, card


def below_target(weights: Path, card: dict[str, Any]) -> str:
    """The warning for a model whose card says it misses its accuracy target (``meets_target``)."""
    target = card.get("accuracy_target") or {}
    got = target.get("measured") or {}
    numbers = ", ".join(f"{_statistic(k)} {got[k]:.3g} {_unit(k)} (target <= {target[k]:g} {_unit(k)})"
                        for k in got if isinstance(got[k], (int, float)) and k in target)
    numbers = numbers or "see its card"
    return (f"{weights}: this PINN misses its accuracy target (tube-1 tip error {numbers}): "
            f"its shapes and its planning margin are that far from the exact model's; train it longer or "
            f"use --backend cosserat")


def _statistic(key: str) -> str:
    """``tube1_tip_p99_9_mm`` -> ``p99.9``; ``tube1_tip_max_pct_length`` -> ``max`` (older cards)."""
    return key.removeprefix("tube1_tip_").removesuffix("_mm").removesuffix("_pct_length").replace("_", ".")


def _unit(key: str) -> str:
    return "% of arc length" if key.endswith("_pct_length") else "mm"
