"""Training checkpoints beside a model (``NAME.ckpt.safetensors`` weights and Adam state,
``NAME.ckpt.json`` step, time, recipe, seed, robot): written while `ctrplan train` runs, read by
``--resume``, removed once the model is written."""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors.torch import load_file, save

from ctrplan.base.dataio import atomic_write
from ctrplan.base.errors import InputError
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot


def checkpoint_paths(out: Path) -> tuple[Path, Path]:
    return out.with_suffix(".ckpt.safetensors"), out.with_suffix(".ckpt.json")


def save_checkpoint(out: Path, net: PinnNet, opt: torch.optim.Optimizer, meta: dict) -> None:
    weights, info = checkpoint_paths(out)
    tensors = {f"net.{k}": v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    if isinstance(opt, torch.optim.Adam):
        for i, p in enumerate(net.parameters()):
            st = opt.state.get(p)
            if st:
                tensors[f"adam.{i}.exp_avg"] = st["exp_avg"].detach().cpu().contiguous()
                tensors[f"adam.{i}.exp_avg_sq"] = st["exp_avg_sq"].detach().cpu().contiguous()
                meta["adam_step"] = float(st["step"])
    weights.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(weights, "wb") as fh:  # a Ctrl-C mid-write leaves the previous checkpoint
        fh.write(save(tensors))
    with atomic_write(info) as fh:
        fh.write(json.dumps(meta, indent=2))


def remove_checkpoint(out: Path) -> None:
    """Delete the checkpoint beside ``out`` (after a finished run it has nothing left to resume)."""
    for path in checkpoint_paths(out):
        path.unlink(missing_ok=True)


def checkpoint_meta(out: Path) -> dict | None:
    """The record of the checkpoint beside ``out`` (its step, training time, robot, recipe, seed),
    with ``file`` (its weights); None when there is none. `InputError` if it cannot be read."""
    weights, info = checkpoint_paths(out)
    if not weights.exists() or not info.exists():
        return None
    try:
        meta = json.loads(info.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{info}: unreadable checkpoint record ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("step"), int):
        raise InputError(f"{info}: not a ctrplan training checkpoint")
    return {**meta, "file": str(weights)}


def check_checkpoint(out: Path, robot: Robot) -> dict:
    """`checkpoint_meta` of ``out``; an `InputError` when there is none or it was made for another
    robot than ``robot`` (by fingerprint)."""
    meta = checkpoint_meta(out)
    if meta is None:
        raise InputError(f"{checkpoint_paths(out)[0]}: no checkpoint to resume from")
    made_for = meta.get("robot_fingerprint")  # None: a checkpoint of an older ctrplan
    if made_for is not None and made_for != robot.fingerprint:
        raise InputError(f"{meta['file']}: checkpoint of robot {meta.get('robot', '?')!r} (fingerprint "
                         f"{str(made_for)[:12]}), not of robot {robot.name!r} (fingerprint "
                         f"{robot.fingerprint[:12]}); resume with the robot it was made for (--robot) "
                         f"or start afresh without --resume")
    return meta


def load_checkpoint(out: Path, net: PinnNet, opt: torch.optim.Optimizer, device) -> dict:
    weights, info = checkpoint_paths(out)
    if not weights.exists() or not info.exists():
        raise InputError(f"{weights}: no checkpoint to resume from")
    tensors = load_file(str(weights), device=str(device))
    try:
        net.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("net.")})
    except RuntimeError as exc:
        raise InputError(f"{weights}: checkpoint weights do not fit this network ({exc})") from None
    meta = json.loads(info.read_text())
    if isinstance(opt, torch.optim.Adam):
        for i, p in enumerate(net.parameters()):
            if f"adam.{i}.exp_avg" in tensors:
                opt.state[p] = {"step": torch.tensor(meta.get("adam_step", 0.0)),
                                "exp_avg": tensors[f"adam.{i}.exp_avg"],
                                "exp_avg_sq": tensors[f"adam.{i}.exp_avg_sq"]}
    return meta
