"""Training loop for the PINN: recipes, on-device sampling, hard-example mining, checkpoints and
resume (DeepXDE style: ``Trainer(robot, data, net).compile(recipe).train(out)``; data, losses,
optimiser and schedule are separate small objects).

Recipes:

* ``fast`` (default) -- what a 2-core CPU can do well in half an hour: Adam on mini-batches of dense
  supervision from exact Cosserat states (the shooting solver gives thousands of full solutions a
  second, so exact data is nearly free), tip rows, hard-example mining (`ctrplan.training.mining`:
  half of every batch comes from fresh configurations where the network was worst), the ODE and
  boundary residuals kept as physics terms, hard constraints in the output (see `PinnNet`) and a
  cosine learning-rate schedule fitted to the time budget.
* ``paper`` -- the paper's setup: fixed 20,000 collocation / 1,000 boundary / 1,000 tip-observation
  samples, L2-norm group losses, L-BFGS with strong-Wolfe line search, full batch.
* ``polish`` -- full-batch L-BFGS on dense supervision and tip observations, after another recipe
  (``--init``).
* ``finetune`` -- the paper's stage (b): continues a trained model on measured tube tips
  (`train(observations=...)`) with the ODE and boundary residuals kept on a fixed collocation set, so
  the model stays physical.

Over 500 lines because the loop, its checkpoints and resume share one state (step, optimiser,
schedule, samplers, budget): split apart, a resumed run could restore part of it.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save

from ctrplan.base.dataio import atomic_write
from ctrplan.base.errors import InputError
from ctrplan.base.machine import cpu_model
from ctrplan.kinematics.model_file import save_model
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot
from ctrplan.training.budget import TimeBudget
from ctrplan.training.evaluate import accuracy_verdict
from ctrplan.training.mining import HardExamples, Mining
from ctrplan.training.physics import TubeTensors
from ctrplan.training.samples import DenseStates, solve_dense, state_scales
from ctrplan.training.terms import Losses, default_weights

#: Seconds of training between two checkpoints.
CHECKPOINT_EVERY_S = 120.0


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
    hidden: int = 100               # network width and depth (the paper's 6 x 100)
    layers: int = 6
    tip_rows: float = 0.0           # extra supervised rows at the tip (s = l1), per dense row
    orientation_weight: float = 1.0  # weight of the quaternion residual in the dense supervision
    physics_every: int = 1          # compute the ODE / boundary terms every k steps
    mining: Mining | None = None    # hard-example mining (`ctrplan.training.mining`)
    minutes: float | None = None    # default time budget


RECIPES = {
    # measured on the nominal robot, 25 min on one (shared) CPU thread, tube-1 tip error on 2,000
    # unseen configurations: this recipe mean 0.20 / max 1.81 mm; physics terms every 4th step instead
    # of every 20th 0.31 / 2.34 mm (a fifth fewer steps and a worse fit); tip rows 1.0 per dense row on
    # 17 points 0.40 / 2.11 mm (the backbone away from the tip 2.5 x worse)
    "fast": Recipe(name="fast", optimizer="adam", steps=1_000_000, lr=2e-3, collocation=1024, boundary=256,
                   observations=0, dense_configs=100_000, dense_points=33, dense_batch=4096,
                   resample=True, weights={"ode": 0.05, "bc": 0.05, "obs": 0.0, "dense": 1.0},
                   harmonics=4, tip_rows=0.25, orientation_weight=10.0, physics_every=20,
                   mining=Mining(), minutes=25.0),
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
        except TypeError as exc:
            raise InputError(f"overrides: mining: {exc} (fields: {', '.join(Mining.__dataclass_fields__)})"
                             ) from None
    return replace(RECIPES[name], **values)


def hardware(device: torch.device) -> str:
    """What trained the model: GPU name, or CPU model and thread count; with the torch version."""
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (CUDA), torch {torch.__version__}"
    return f"{cpu_model()}, {torch.get_num_threads()} threads, torch {torch.__version__}"


class Sampler:
    """Draws training batches on the training device; step ``k`` always gives the same batch."""

    def __init__(self, robot: Robot, seed: int, device: torch.device):
        self.lo = torch.tensor(robot.domain.box_lower, dtype=torch.float32, device=device)
        self.hi = torch.tensor(robot.domain.box_upper, dtype=torch.float32, device=device)
        self.joints_from_box = torch.tensor(robot.domain.joints_from_box, dtype=torch.float32, device=device)
        self.seed, self.device, self.n_tubes = seed, device, robot.n_tubes

    def generator(self, step: int, stream: int) -> torch.Generator:
        g = torch.Generator(device=self.device)
        g.manual_seed(hash((self.seed, step, stream)) & 0x7FFF_FFFF_FFFF)
        return g

    def joints(self, n: int, g: torch.Generator) -> torch.Tensor:
        """``n`` joints (n, 2N) uniform in the domain box (`JointDomain`: relative rotations too)."""
        x = self.lo + (self.hi - self.lo) * torch.rand(n, 2 * self.n_tubes, generator=g, device=self.device)
        return x @ self.joints_from_box.T

    def collocation(self, n: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.rand(n, generator=g, device=self.device), self.joints(n, g)


class TrainingDivergedError(InputError):
    """The loss became NaN or inf: the message names the step, the terms that did and the recipe
    field to change (``--set lr=...``)."""

    def __init__(self, step: int, recipe: Recipe, terms: dict[str, float]):
        bad = [k for k, v in terms.items() if not math.isfinite(v)] or ["total"]
        super().__init__(
            f"training diverged at step {step}: loss term(s) {', '.join(bad)} became NaN/inf with "
            f"learning rate {recipe.lr:g} (recipe {recipe.name}); retry with a smaller one, e.g. "
            f"--set lr={recipe.lr / 10:g}")


@dataclass
class TrainResult:
    net: PinnNet
    steps: int
    wall_time_s: float
    history: list[dict]
    card: dict


@dataclass(frozen=True)
class Observations:
    """Tube tips to fit: joints q (B, 2N) as the network sees them (offsets applied), tips (B, N, 3)
    mm in the robot frame (NaN where a tube was not measured) and, for a sensor on the tip, the
    tracked point's offset (3,) mm in the tip frame of tube 1."""

    q: np.ndarray
    tips_mm: np.ndarray
    sensor_offset_mm: np.ndarray | None = None


@dataclass
class TrainingData:
    """What the losses draw on, on the training device: exact Cosserat solutions (dense supervision,
    tip observations, output scales), the hard examples found by mining, the sampler and, without
    resampling, the fixed collocation and boundary sets. Joints are as the network sees them (the
    robot's joint offsets applied)."""

    pool: DenseStates
    sampler: Sampler
    dense_q: torch.Tensor
    dense_x: torch.Tensor
    sigma_grid: torch.Tensor
    obs_q: torch.Tensor
    obs_tips: torch.Tensor
    obs_sensor_offset: torch.Tensor | None
    fixed_colloc: tuple[torch.Tensor, torch.Tensor] | None
    fixed_bc: torch.Tensor | None
    hard: HardExamples | None

    @classmethod
    def build(cls, robot: Robot, recipe: Recipe, seed: int, device: torch.device,
              observations: Observations | None = None,
              progress: Callable[[int, int], None] | None = None,
              deadline: float | None = None, budget: TimeBudget | None = None) -> TrainingData:
        """Solve the exact pool (its size: `pool_size`; ``progress(done, total)`` while it is solved;
        cut short at ``deadline``, see `solve_dense`, and then recorded in ``budget``) and draw the
        fixed sets; ``observations`` (see `train`) replace the pool's tips."""
        n_exact = pool_size(recipe)
        pool = solve_dense(robot, robot.sample_joints(n_exact, np.random.default_rng(seed)),
                           recipe.dense_points, progress, deadline)
        if budget is not None and len(pool) + len(pool.unsolved) < n_exact:
            budget.cut(f"exact data: {len(pool) + len(pool.unsolved):,} of {n_exact:,} configurations solved")
        if not len(pool):
            raise InputError(f"robot {robot.name!r}: the exact solver solved none of {n_exact} random "
                             f"configurations of its domain; check the domain with `ctrplan stability`")

        def to_dev(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(a, dtype=np.float32), device=device)

        q_model = robot.apply_offset(pool.q)
        obs = observations or Observations(q_model[:recipe.observations], pool.tips[:recipe.observations])
        offset = None if obs.sensor_offset_mm is None else to_dev(obs.sensor_offset_mm)
        sampler = Sampler(robot, seed, device)
        fixed_colloc = None if recipe.resample else sampler.collocation(recipe.collocation,
                                                                        sampler.generator(0, 1))
        fixed_bc = None if recipe.resample else sampler.joints(recipe.boundary, sampler.generator(0, 2))
        hard = (HardExamples(robot, recipe.mining, recipe.dense_points, seed, device)
                if recipe.mining else None)
        return cls(pool=pool, sampler=sampler, dense_q=to_dev(q_model), dense_x=to_dev(pool.states),
                   sigma_grid=to_dev(pool.sigma), obs_q=to_dev(obs.q), obs_tips=to_dev(obs.tips_mm),
                   obs_sensor_offset=offset,
                   fixed_colloc=fixed_colloc, fixed_bc=fixed_bc, hard=hard)


def pool_size(recipe: Recipe) -> int:
    """Configurations the exact pool of ``recipe`` solves: the largest of its dense configurations,
    its observations and 2000."""
    return max(recipe.dense_configs, recipe.observations, 2000)


def make_optimizer(recipe: Recipe, params) -> torch.optim.Optimizer:
    """Adam, or full-batch L-BFGS with strong-Wolfe line search, as the recipe says."""
    if recipe.optimizer == "adam":
        return torch.optim.Adam(params, lr=recipe.lr)
    if recipe.optimizer == "lbfgs":
        return torch.optim.LBFGS(params, lr=recipe.lr, max_iter=20, tolerance_grad=1e-10,
                                 tolerance_change=1e-12, history_size=recipe.lbfgs_history,
                                 line_search_fn="strong_wolfe")
    raise InputError(f"recipe {recipe.name}: unknown optimizer {recipe.optimizer!r}")


@dataclass(frozen=True)
class CosineSchedule:
    """Adam's learning rate: cosine decay from ``lr`` to ``lr_final`` over whichever ends first, the
    step budget or the time limit, after a linear warm-up of ``warmup_steps``."""

    lr: float
    lr_final: float
    steps: int
    warmup_steps: int = 0
    time_limit_s: float | None = None

    @classmethod
    def of(cls, recipe: Recipe, time_limit_s: float | None) -> CosineSchedule:
        return cls(recipe.lr, recipe.lr_final, recipe.steps, recipe.warmup_steps, time_limit_s)

    def __call__(self, step: int, elapsed_s: float) -> float:
        frac = step / max(self.steps - 1, 1)
        if self.time_limit_s:
            frac = max(frac, elapsed_s / self.time_limit_s)
        frac = min(frac, 1.0)
        lr = self.lr_final + 0.5 * (self.lr - self.lr_final) * (1 + math.cos(math.pi * frac))
        if step < self.warmup_steps:
            lr *= (step + 1) / self.warmup_steps
        return lr


def _checkpoint_paths(out: Path) -> tuple[Path, Path]:
    return out.with_suffix(".ckpt.safetensors"), out.with_suffix(".ckpt.json")


def _save_checkpoint(out: Path, net: PinnNet, opt: torch.optim.Optimizer, meta: dict) -> None:
    weights, info = _checkpoint_paths(out)
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
    for path in _checkpoint_paths(out):
        path.unlink(missing_ok=True)


def checkpoint_meta(out: Path) -> dict | None:
    """The record of the checkpoint beside ``out`` (its step, training time, robot, recipe, seed),
    with ``file`` (its weights); None when there is none. `InputError` if it cannot be read."""
    weights, info = _checkpoint_paths(out)
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
        raise InputError(f"{_checkpoint_paths(out)[0]}: no checkpoint to resume from")
    made_for = meta.get("robot_fingerprint")  # None: a checkpoint of an older ctrplan
    if made_for is not None and made_for != robot.fingerprint:
        raise InputError(f"{meta['file']}: checkpoint of robot {meta.get('robot', '?')!r} (fingerprint "
                         f"{str(made_for)[:12]}), not of robot {robot.name!r} (fingerprint "
                         f"{robot.fingerprint[:12]}); resume with the robot it was made for (--robot) "
                         f"or start afresh without --resume")
    return meta


def _load_checkpoint(out: Path, net: PinnNet, opt: torch.optim.Optimizer, device) -> dict:
    weights, info = _checkpoint_paths(out)
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


class Trainer:
    """Trains a `PinnNet` (DeepXDE style): ``Trainer(robot, data, net).compile(recipe).train(out)``,
    then ``finish(out)`` writes the model and its card. `train` below is the one-call form."""

    def __init__(self, robot: Robot, data: TrainingData, net: PinnNet, *, data_time_s: float = 0.0,
                 budget: TimeBudget | None = None):
        self.robot, self.data, self.net, self.data_time_s = robot, data, net, data_time_s
        self.device = data.dense_q.device
        self.budget = budget

    def compile(self, recipe: Recipe, *, seed: int = 0, time_limit_s: float | None = None) -> Trainer:
        """Set the recipe's losses, optimiser and learning-rate schedule; start at step 0."""
        self.recipe, self.seed = recipe, seed
        self.losses = Losses(recipe, self.data, TubeTensors.from_robot(self.robot, device=self.device))
        self.optimizer = make_optimizer(recipe, self.net.parameters())
        self.step, self.elapsed_before_s, self.history = 0, 0.0, []
        self._stats: dict = {}
        return self.limit(time_limit_s)

    def limit(self, time_limit_s: float | None) -> Trainer:
        """Set the training time limit (s, None: the step budget only) and fit the schedule to it."""
        self.time_limit_s = time_limit_s
        self.schedule = CosineSchedule.of(self.recipe, time_limit_s)
        return self

    def resume(self, out: Path) -> Trainer:
        """Continue from the checkpoint beside ``out`` (same robot, recipe and seed only). Training
        ends where the checkpointed run would have ended, or earlier if this run's time limit is
        shorter than what that run had left."""
        check_checkpoint(out, self.robot)
        meta = _load_checkpoint(out, self.net, self.optimizer, self.device)
        if meta.get("recipe") != asdict(self.recipe) or meta.get("seed") != self.seed:
            raise InputError(f"{out}: checkpoint was made with another recipe or seed; "
                             "resume with the same --recipe/--seed or start afresh")
        self.step, self.elapsed_before_s = meta["step"], meta["elapsed_s"]
        self.history = meta.get("history", [])
        if self.time_limit_s is not None:
            limit = self.elapsed_before_s + self.time_limit_s
            self.limit(min(limit, meta.get("time_limit_s") or limit))
        return self

    def _elapsed_s(self) -> float:
        return self.elapsed_before_s + time.perf_counter() - self._t0

    def _out_of_time(self) -> bool:
        return self.time_limit_s is not None and self._elapsed_s() >= self.time_limit_s

    def _adam_step(self) -> torch.Tensor:
        for group in self.optimizer.param_groups:
            group["lr"] = self.schedule(self.step, self._elapsed_s())
        self.optimizer.zero_grad(set_to_none=True)
        total, self._stats = self.losses(self.net, self.step)
        total.backward()
        self.optimizer.step()
        return total

    def _lbfgs_step(self) -> torch.Tensor:
        def closure(k: int = self.step, out: dict = self._stats) -> torch.Tensor:
            self.optimizer.zero_grad(set_to_none=True)
            total, stats = self.losses(self.net, k)
            total.backward()
            out.update(stats)
            return total

        return self.optimizer.step(closure)

    def _checkpoint(self, out: Path, elapsed_s: float) -> None:
        _save_checkpoint(out, self.net, self.optimizer,
                         {"step": self.step, "elapsed_s": elapsed_s, "recipe": asdict(self.recipe),
                          "seed": self.seed, "robot": self.robot.name,
                          "robot_fingerprint": self.robot.fingerprint, "time_limit_s": self.time_limit_s,
                          "history": self.history})

    def _mine(self) -> dict:
        """A mining round (`HardExamples.mine`) when one is due; its fresh-configuration tail."""
        hard, m = self.data.hard, self.recipe.mining
        if hard is None or self.step % m.every:
            return {}
        rnd = hard.mine(self.net, self.step)
        return {"fresh_tip_p99_9_mm": rnd.tip_mm["p99_9"], "fresh_tip_max_mm": rnd.tip_mm["max"],
                "fresh_orientation_max_deg": rnd.orientation_deg["max"]}

    def train(self, out: Path, *, checkpoint_every_s: float = CHECKPOINT_EVERY_S,
              progress: Callable[[int, int, dict], None] | None = None, min_steps: int = 0) -> Trainer:
        """Run to the recipe's step budget or the time limit (at least ``min_steps`` steps),
        checkpointing beside ``out`` and mining hard examples as the recipe says.
        ``progress(step, total, stats)`` is called every 10 steps and at the last one; ``stats`` has
        the loss terms, ``time_s`` (the training time so far) and, after mining rounds, the network's
        tail on the round's fresh configurations."""
        steps = self.recipe.steps
        one_step = self._adam_step if self.recipe.optimizer == "adam" else self._lbfgs_step
        self._t0 = last_ckpt = time.perf_counter()
        fresh: dict = {}
        first = self.step
        while self.step < steps and (self.step < first + min_steps or not self._out_of_time()):
            total = one_step()
            self.step += 1
            fresh = self._mine() or fresh
            last = self.step == steps or self._out_of_time()
            if self.step % 10 and not last:
                continue  # host-device syncs only every 10 steps
            loss = float(total.detach())
            if not math.isfinite(loss):
                raise TrainingDivergedError(self.step, self.recipe,
                                            {k: float(v) for k, v in self._stats.items()})
            now = time.perf_counter()
            elapsed = self.elapsed_before_s + now - self._t0
            values = {"loss": loss, **{k: float(v) for k, v in self._stats.items()}, **fresh}
            if self.step % 50 == 0 or last:
                self.history.append({"step": self.step, "time_s": round(elapsed, 2), **values})
            if progress is not None:
                progress(self.step, steps, {**values, "time_s": elapsed})
            if now - last_ckpt > checkpoint_every_s:
                self._checkpoint(out, self.elapsed_before_s + now - self._t0)
                last_ckpt = now
        self.wall_time_s = self._elapsed_s() + self.data_time_s
        self._checkpoint(out, self.wall_time_s - self.data_time_s)
        return self

    def _mining_record(self) -> dict:
        """The card's record of hard-example mining: rounds, pool, time and their history."""
        hard = self.data.hard
        return {"rounds": len(hard.rounds), "hard_pool": len(hard), "seconds": round(hard.seconds, 1),
                "unsolved_candidates": sum(r.unsolved for r in hard.rounds),
                "history": [r.to_json() for r in hard.rounds[::max(1, len(hard.rounds) // 20)]],
                "last": hard.rounds[-1].to_json() if hard.rounds else None}

    def finish(self, out: Path, *, evaluate: Callable[[PinnNet], dict] | None = None,
               calibrate: Callable[[PinnNet], dict] | None = None,
               extra_card: dict | None = None) -> TrainResult:
        """Evaluate and calibrate the network, write ``out.safetensors`` and its card ``out.json``."""
        net = self.net.cpu().eval()
        recipe, step, wall = self.recipe, self.step, self.wall_time_s
        metrics = evaluate(net) if evaluate is not None else {}
        extra = dict(extra_card or {})
        stage = {"recipe": asdict(recipe), "steps": step, "wall_time_s": round(wall, 1),
                 "hardware": hardware(self.device), "seed": self.seed}
        card = {
            **extra,
            "stages": [*extra.get("stages", []), stage],
            "recipe": asdict(recipe),
            "seed": self.seed,
            "steps": step,
            "samples": {
                "exact_solutions": len(self.data.pool),
                "dense_points_per_solution": recipe.dense_points if recipe.dense_configs else 0,
                "collocation": recipe.collocation * (step if recipe.resample else 1),
                "boundary": recipe.boundary * (step if recipe.resample else 1),
                "observations": len(self.data.obs_q),
            },
            "wall_time_s": round(wall, 1),
            "data_generation_s": round(self.data_time_s, 1),
            "unsolved_configurations": self.data.pool.unsolved_report(),
            "hardware": hardware(self.device),
            "metrics": metrics,
            "history_tail": self.history[-5:],
        }
        card |= {"mining": self._mining_record()} if self.data.hard is not None else {}
        card |= {ERROR_BOUND_KEY: calibrate(net)} if calibrate is not None else {}
        if self.budget is not None:  # a run of `ctrplan train` (a fine-tuned model has its own table)
            card |= {"time_limit": self.budget.to_json(), **accuracy_verdict(metrics)}
        save_model(net, self.robot, out, card)
        return TrainResult(net=net, steps=step, wall_time_s=wall, history=self.history, card=card)


def new_net(robot: Robot, recipe: Recipe, data: TrainingData) -> PinnNet:
    """An untrained network of the recipe's shape and encoding for ``robot``, its output scales
    from the exact states of ``data``'s pool."""
    return PinnNet(robot, hidden=recipe.hidden, layers=recipe.layers,
                   scales=state_scales(data.pool, recipe.features), features=recipe.features,
                   harmonics=recipe.harmonics)


def train(robot: Robot, recipe: Recipe, out: Path, *, seed: int = 0, device: str = "cpu",
          resume: bool = False, init_from: PinnNet | None = None, time_limit_s: float | None = None,
          checkpoint_every_s: float = CHECKPOINT_EVERY_S,
          progress: Callable[[int, int, dict], None] | None = None,
          data_progress: Callable[[int, int], None] | None = None,
          evaluate: Callable[[PinnNet], dict] | None = None,
          calibrate: Callable[[PinnNet], dict] | None = None,
          observations: Observations | None = None,
          extra_card: dict | None = None, budget: TimeBudget | None = None) -> TrainResult:
    """Train a PINN for ``robot`` with ``recipe``; write ``out.safetensors`` + ``out.json``.

    ``init_from`` continues from an existing network (its input encoding and output scales are kept).
    ``data_progress(done, total)`` reports while the exact pool is solved, ``progress(step, total,
    stats)`` every few steps; ``evaluate(net) -> metrics`` runs at the end (metrics go into the model
    card), and ``calibrate(net) -> error bound`` (the planner's margin, in the card too). Stops at
    ``recipe.steps`` or after ``time_limit_s`` (default: the recipe's ``minutes``), data generation
    included. ``observations`` (measured tips, paper stage b) replace the Cosserat
    tip observations; ``extra_card`` holds extra model-card fields. The card's ``stages`` lists
    the training stages: ``extra_card["stages"]`` (of the ``init_from`` model), then this one. A
    ``budget`` (`TimeBudget`; replaces ``time_limit_s``) bounds the whole run, exact pool included;
    the card then records it and, from ``evaluate``, the `accuracy_verdict`.
    """
    dev = torch.device(device)
    torch.manual_seed(seed)
    t_start = time.perf_counter()
    own = budget is None  # then no deadline on the exact data: only the training loop is limited
    budget = budget or TimeBudget(time_limit_s if time_limit_s is not None
                                  else (recipe.minutes * 60 if recipe.minutes else None))
    data = TrainingData.build(robot, recipe, seed, dev, observations, data_progress,
                              deadline=None if own else budget.data_deadline(), budget=budget)
    net = (new_net(robot, recipe, data) if init_from is None else init_from).to(dev).train()
    net.requires_grad_(True)
    data_time_s = time.perf_counter() - t_start
    trainer = Trainer(robot, data, net, data_time_s=data_time_s, budget=None if own else budget)
    trainer.compile(recipe, seed=seed)  # the first optimiser loads torch's compiler: seconds
    trainer.limit(budget.training_s(data.pool.solved_per_s))
    if resume:
        trainer.resume(out)
    trainer.train(out, checkpoint_every_s=checkpoint_every_s, progress=progress, min_steps=0 if own else 1)
    return trainer.finish(out, evaluate=evaluate, calibrate=calibrate, extra_card=extra_card)
