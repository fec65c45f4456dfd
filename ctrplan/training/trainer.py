"""Training loop for the PINN: on-device sampling, hard-example mining, the time-to-target monitor,
checkpoints and resume (DeepXDE style: ``Trainer(robot, data, net).compile(recipe).train(out)``; data,
losses, optimiser and schedule are separate small objects; recipes in `ctrplan.training.recipes`).

Recipes:

* ``fast`` (default) -- what a 2-core CPU can do well in 20 minutes: Adam on mini-batches of dense
  supervision from exact Cosserat states (the shooting solver gives thousands of full solutions a
  second, so exact data is nearly free; half of them with the translations near their limits), tip
  rows, hard-example mining (`ctrplan.training.mining`: half of every batch comes from fresh
  configurations where the network was worst), the ODE and boundary residuals kept as physics terms,
  hard constraints in the output (see `PinnNet`) and a cosine learning-rate schedule fitted to the
  time budget; `ctrplan train` starts it from the nearest trained model (`ctrplan.training.transfer`).
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

import math
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ctrplan.base.errors import InputError
from ctrplan.base.machine import cpu_model
from ctrplan.kinematics.model_file import save_model
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot
from ctrplan.training.budget import TimeBudget, now
from ctrplan.training.checkpoints import check_checkpoint, checkpoint_meta, load_checkpoint, save_checkpoint
from ctrplan.training.evaluate import accuracy_verdict
from ctrplan.training.mining import HardExamples
from ctrplan.training.physics import TubeTensors
from ctrplan.training.recipes import Recipe, pool_size
from ctrplan.training.samples import DenseStates, frame_tube, pool_joints, solve_dense, state_scales
from ctrplan.training.target import MONITOR_EVERY_S, Monitor, time_to_target
from ctrplan.training.terms import Losses
from ctrplan.training.transfer import Transfer

#: Seconds of training between two checkpoints.
CHECKPOINT_EVERY_S = 120.0


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
              deadline: float | None = None, budget: TimeBudget | None = None,
              mining_worker: bool = False) -> TrainingData:
        """Solve the exact pool (its size: `pool_size`; ``progress(done, total)`` while it is solved;
        cut short at ``deadline``, see `solve_dense`, and then recorded in ``budget``) and draw the
        fixed sets; ``observations`` (see `train`) replace the pool's tips. With ``mining_worker``
        the mining rounds are solved ahead in a process of their own (`ctrplan.training.rounds`)."""
        n_exact = pool_size(recipe)
        joints = pool_joints(robot, n_exact, np.random.default_rng(seed), recipe.edge_share)
        pool = solve_dense(robot, joints, recipe.dense_points, progress, deadline)
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
        hard = (HardExamples(robot, recipe.mining, recipe.dense_points, seed, device, mining_worker)
                if recipe.mining else None)
        return cls(pool=pool, sampler=sampler, dense_q=to_dev(q_model), dense_x=to_dev(pool.states),
                   sigma_grid=to_dev(pool.sigma), obs_q=to_dev(obs.q), obs_tips=to_dev(obs.tips_mm),
                   obs_sensor_offset=offset,
                   fixed_colloc=fixed_colloc, fixed_bc=fixed_bc, hard=hard)


def make_optimizer(recipe: Recipe, params) -> torch.optim.Optimizer:
    """Adam, or full-batch L-BFGS with strong-Wolfe line search, as the recipe says. Adam is torch's
    fused one: one kernel for all parameter tensors (0.15 against 0.5-0.6 ms a step on the CPU)."""
    if recipe.optimizer == "adam":
        return torch.optim.Adam(params, lr=recipe.lr, fused=True)
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


class Trainer:
    """Trains a `PinnNet` (DeepXDE style): ``Trainer(robot, data, net).compile(recipe).train(out)``,
    then ``finish(out)`` writes the model and its card. `train` below is the one-call form."""

    def __init__(self, robot: Robot, data: TrainingData, net: PinnNet, *, data_time_s: float = 0.0,
                 budget: TimeBudget | None = None, transfer: Transfer | None = None):
        self.robot, self.data, self.net, self.data_time_s = robot, data, net, data_time_s
        self.device = data.dense_q.device
        self.budget = budget
        # `Transfer.to_json` of the model it started from
        self.transferred_from: dict | None = transfer.to_json() if transfer is not None else None

    def compile(self, recipe: Recipe, *, seed: int = 0, time_limit_s: float | None = None) -> Trainer:
        """Set the recipe's losses, optimiser and learning-rate schedule; start at step 0."""
        self.recipe, self.seed = recipe, seed
        self.losses = Losses(recipe, self.data, TubeTensors.from_robot(self.robot, device=self.device))
        self.optimizer = make_optimizer(recipe, self.net.parameters())
        self.step, self.elapsed_before_s, self.history = 0, 0.0, []
        self._stats: dict = {}
        self.monitor: Monitor | None = None
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
        meta = load_checkpoint(out, self.net, self.optimizer, self.device)
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
        return self.elapsed_before_s + now() - self._t0

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
        save_checkpoint(out, self.net, self.optimizer,
                         {"step": self.step, "elapsed_s": elapsed_s, "recipe": asdict(self.recipe),
                          "seed": self.seed, "robot": self.robot.name,
                          "robot_fingerprint": self.robot.fingerprint, "time_limit_s": self.time_limit_s,
                          "frame_tube": self.net.frame + 1, "transferred_from": self.transferred_from,
                          "history": self.history})

    def _mine(self) -> dict:
        """A mining round (`HardExamples.mine`) when one is due and ready; its fresh-configuration tail."""
        hard = self.data.hard
        if hard is None or not hard.due(self.step):
            return {}
        rnd = hard.mine(self.net, self.step)
        return {"fresh_tip_p99_9_mm": rnd.tip_mm["p99_9"], "fresh_tip_max_mm": rnd.tip_mm["max"],
                "fresh_orientation_max_deg": rnd.orientation_deg["max"]}

    def train(self, out: Path, *, checkpoint_every_s: float = CHECKPOINT_EVERY_S,
              progress: Callable[[int, int, dict], None] | None = None, min_steps: int = 0) -> Trainer:
        """Run to the recipe's step budget or the time limit (at least ``min_steps`` steps),
        checkpointing beside ``out``, mining hard examples as the recipe says and measuring the
        network with the `watch` monitor every `MONITOR_EVERY_S` seconds and at the end.
        ``progress(step, total, stats)`` is called every 10 steps and at the last one; ``stats`` has
        the loss terms, ``time_s`` (the training time so far), after mining rounds the network's
        tail on the round's fresh configurations, and after the monitor's measurements its tail."""
        one_step = self._adam_step if self.recipe.optimizer == "adam" else self._lbfgs_step
        self._t0 = self._last_ckpt = self._last_watch = now()
        self._fresh: dict = {}
        first, hard = self.step, self.data.hard
        with hard.solving(first) if hard is not None else nullcontext():
            while self.step < self.recipe.steps and (self.step < first + min_steps
                                                     or not self._out_of_time()):
                total = one_step()
                self.step += 1
                self._fresh |= self._mine()
                last = self.step == self.recipe.steps or self._out_of_time()
                if self.step % 10 == 0 or last:  # host-device syncs only every 10 steps
                    self._log(float(total.detach()), last, out, checkpoint_every_s, progress)
        self.wall_time_s = self._elapsed_s() + self.data_time_s
        self._checkpoint(out, self.wall_time_s - self.data_time_s)
        return self

    def watch(self, monitor: Monitor | None) -> Trainer:
        """Measure the network with ``monitor`` (`ctrplan.training.target.Monitor`) while it trains."""
        self.monitor = monitor
        return self

    def run_clock_s(self) -> float:
        """Seconds since the run started: the whole command's (its `TimeBudget`) when it has one."""
        return self.budget.elapsed_s() if self.budget is not None else self.data_time_s + self._elapsed_s()

    def _log(self, loss: float, last: bool, out: Path, checkpoint_every_s: float,
             progress: Callable[[int, int, dict], None] | None) -> None:
        """Every 10 steps: check the loss, record history, measure (when due), report, checkpoint."""
        if not math.isfinite(loss):
            raise TrainingDivergedError(self.step, self.recipe, {k: float(v) for k, v in self._stats.items()})
        t = now()
        elapsed = self.elapsed_before_s + t - self._t0
        if self.monitor is not None and (last or t - self._last_watch >= MONITOR_EVERY_S):
            tip = self.monitor(self.net, self.step, self.run_clock_s()).tip_mm
            self._fresh |= {"unseen_tip_p99_9_mm": tip["p99_9"], "unseen_tip_max_mm": tip["max"]}
            self._last_watch = t
        values = {"loss": loss, **{k: float(v) for k, v in self._stats.items()}, **self._fresh}
        if self.step % 50 == 0 or last:
            self.history.append({"step": self.step, "time_s": round(elapsed, 2), **values})
        if progress is not None:
            progress(self.step, self.recipe.steps, {**values, "time_s": elapsed})
        if t - self._last_ckpt > checkpoint_every_s:
            self._checkpoint(out, elapsed)
            self._last_ckpt = t

    def _mining_record(self) -> dict:
        """The card's record of hard-example mining: rounds, pool, time and their history."""
        hard = self.data.hard
        return {"rounds": len(hard.rounds), "hard_pool": len(hard), "seconds": round(hard.seconds, 1),
                "solved_in": "a worker process" if hard.worker else "the training process",
                "solve_cpu_s": round(hard.solve_cpu_s, 1), "waited_s": round(hard.waited_s, 1),
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
        card |= {"transferred_from": self.transferred_from} if self.transferred_from else {}
        card |= {ERROR_BOUND_KEY: calibrate(net)} if calibrate is not None else {}
        card |= self._verdict(metrics)
        save_model(net, self.robot, out, card)
        return TrainResult(net=net, steps=step, wall_time_s=wall, history=self.history, card=card)

    def _verdict(self, metrics: dict) -> dict:
        """The card's ``time_limit``, accuracy verdict (`accuracy_verdict`: on the card's evaluation
        ``metrics`` or the monitor's last measurement, the larger set) and ``time_to_target``."""
        if not metrics:
            return {"time_limit": self.budget.to_json()} if self.budget is not None else {}
        last = self.monitor.curve[-1] if self.monitor is not None and self.monitor.curve else None
        verdict = accuracy_verdict(metrics, last and last.tip_mm, self.monitor.configurations if last else 0)
        card = {}
        if self.budget is not None:  # a run of `ctrplan train` (a fine-tuned model has its own table)
            card |= {"time_limit": self.budget.to_json(), **verdict}
        if self.monitor is not None:
            judged = verdict["accuracy_target"]["tip_mm"]
            card |= {"time_to_target": time_to_target(self.monitor.curve, judged)}
        return card


def new_net(robot: Robot, recipe: Recipe, data: TrainingData, frame: int | None = None) -> PinnNet:
    """An untrained network of the recipe's shape and encoding for ``robot``, its output scales
    from the exact states of ``data``'s pool; with the equivariant encoding its frame tube is
    ``frame`` (0-based), else the recipe's or (0) the one `frame_tube` picks."""
    if frame is None and recipe.features == "equivariant":
        frame = recipe.frame_tube - 1 if recipe.frame_tube else frame_tube(robot)
    return PinnNet(robot, hidden=recipe.hidden, layers=recipe.layers,
                   scales=state_scales(data.pool, recipe.features), features=recipe.features,
                   harmonics=recipe.harmonics, frame=frame or 0)


def train(robot: Robot, recipe: Recipe, out: Path, *, seed: int = 0, device: str = "cpu",
          resume: bool = False, init_from: PinnNet | None = None, time_limit_s: float | None = None,
          checkpoint_every_s: float = CHECKPOINT_EVERY_S,
          progress: Callable[[int, int, dict], None] | None = None,
          data_progress: Callable[[int, int], None] | None = None,
          evaluate: Callable[[PinnNet], dict] | None = None,
          calibrate: Callable[[PinnNet], dict] | None = None,
          observations: Observations | None = None, extra_card: dict | None = None,
          budget: TimeBudget | None = None, monitor: Monitor | None = None,
          transfer: Transfer | None = None, mining_worker: bool = False) -> TrainResult:
    """Train a PINN for ``robot`` with ``recipe`` from `start_net`; write ``out.safetensors`` + ``.json``.
    ``data_progress(done, total)`` reports while the exact pool is solved, ``progress(step, total,
    stats)`` every few steps; ``evaluate(net) -> metrics`` and ``calibrate(net) -> error bound`` run
    at the end (into the card), ``monitor`` (`ctrplan.training.target.Monitor`) while it trains (the
    card's ``time_to_target``). Stops at ``recipe.steps`` or after ``time_limit_s`` (default: the
    recipe's ``minutes``), or when the ``budget`` (`TimeBudget`, then recorded in the card with the
    `accuracy_verdict`) of the whole run, exact pool included, runs out. ``observations`` (measured
    tips, paper stage b) replace the Cosserat tip observations; ``extra_card``: more card fields (its
    ``stages``: those of ``init_from``, then this one's). ``mining_worker``: solve the mining rounds
    ahead on another core (`ctrplan.training.rounds`; the same rounds either way)."""
    dev = torch.device(device)
    torch.manual_seed(seed)
    recipe = transfer.recipe(recipe) if transfer is not None else recipe
    t_start = now()
    own = budget is None  # then no deadline on the exact data: only the training loop is limited
    budget = budget or TimeBudget(time_limit_s if time_limit_s is not None
                                  else (recipe.minutes * 60 if recipe.minutes else None))
    data = TrainingData.build(robot, recipe, seed, dev, observations, data_progress,
                              deadline=None if own else budget.data_deadline(), budget=budget,
                              mining_worker=mining_worker)
    net = start_net(robot, recipe, data, init_from, transfer, out if resume else None)
    net = net.to(dev).train().requires_grad_(True)
    trainer = Trainer(robot, data, net, data_time_s=now() - t_start, budget=None if own else budget,
                      transfer=transfer)
    trainer.compile(recipe, seed=seed).watch(monitor)  # the first optimiser loads torch's compiler: seconds
    trainer.limit(budget.training_s(data.pool.solved_per_s))
    if resume:
        trainer.resume(out)
    trainer.train(out, checkpoint_every_s=checkpoint_every_s, progress=progress, min_steps=0 if own else 1)
    return trainer.finish(out, evaluate=evaluate, calibrate=calibrate, extra_card=extra_card)


def start_net(robot: Robot, recipe: Recipe, data: TrainingData, init_from: PinnNet | None,
              transfer: Transfer | None, resume_from: Path | None) -> PinnNet:
    """The network training starts from: ``init_from`` as it is, or a new one for ``robot`` with
    ``transfer``'s layers, or one with the frame tube of the checkpoint beside ``resume_from``."""
    if init_from is not None:
        return init_from
    if transfer is not None:
        return transfer.apply(new_net(robot, recipe, data, frame=transfer.frame))
    meta = checkpoint_meta(resume_from) if resume_from is not None else None
    return new_net(robot, recipe, data, frame=meta.get("frame_tube", 1) - 1 if meta else None)
