"""The optimiser: an Optuna study of designs in an RDB storage, its trials run on any executor.

**Sampler.** Multi-objective TPE, multivariate, with constraints: a design has a few coupled
continuous parameters (how far a tube reaches sideways depends on curvature times length) and one
categorical choice of nested stock sizes, and each trial costs seconds to a minute (a stability sweep
and one planning problem per target). TPE models where good designs lie from the first few dozen
trials, treats the catalogue choice natively as a categorical, and the multivariate variant models
the parameters jointly instead of one at a time; NSGA-II would need a population of ~50 per
generation for many generations -- more trials than a study here affords. Infeasible designs (not
buildable, over-strained, snapping, no way in) are told to the sampler with positive constraint
values, so it learns to avoid them and never ranks them among the good ones.

**Storage.** Any SQLAlchemy URL (`optuna.storages.RDBStorage`); by default a SQLite file in the
output folder, which optuna-dashboard reads. A study remembers its task (a digest of everything that
decides an evaluation) and its seed; continuing it with another task or seed is refused. The trial
budget counts the study's finished trials, so the same command continues an interrupted study, and
one with the budget already spent only rewrites the outputs. Each trial keeps its whole evaluation
record as the user attribute ``record``; the base design's record is the study attribute
``nominal``.

**Executors.** The driver (this process) asks the sampler for a design, hands its evaluation to a
`ctrplan.base.parallel` pool (this process, local worker processes or Ray actors, each with its own
`ctrplan.design.evaluate.DesignContext`) and tells the result back, keeping as many trials in flight
as there are workers. With one worker a study is reproducible
for a seed: the sampler is seeded, and each evaluation is a function of its parameters and the seed
(`ctrplan.design.evaluate`).
"""

from __future__ import annotations

import hashlib
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import optuna
from optuna.trial import TrialState

from ctrplan.base.errors import InputError
from ctrplan.base.parallel import open_pool
from ctrplan.design.evaluate import DesignContext, DesignJob, evaluate_job
from ctrplan.design.objectives import Objective
from ctrplan.design.record import DesignRecord
from ctrplan.design.space import distributions
from ctrplan.design.task import DesignTask

RECORD = "record"
NOMINAL = "nominal"
_DIGEST = "ctrplan_task_digest"
_SEED = "ctrplan_seed"
#: Random designs before TPE models the good ones.
STARTUP_TRIALS = 10

#: ``report(trial, record, finished)`` after each evaluation: the Optuna trial number (None for the
#: base design), its record and the study's finished trials so far.
Report = Callable[[int | None, DesignRecord, int], None]


def _quiet(_trial: int | None, _record: DesignRecord, _finished: int) -> None:
    return None


def default_storage(out: Path) -> str:
    """SQLite in the output folder, as given (a relative folder gives a URL relative to the working
    directory, like every other output, so reports name no machine's paths)."""
    return f"sqlite:///{Path(out) / 'study.db'}"


def constraint_values(task: DesignTask, record: DesignRecord) -> dict[str, float]:
    """Optuna constraints (feasible when all are <= 0): the strain excess over the limit, and 1 for
    any other unmet condition."""
    other = not record.feasible and record.infeasible.constraint != "max_strain"
    return {"max_strain": record.max_strain - task.max_strain, "feasible": float(other)}


def open_study(task: DesignTask, storage: str, name: str, seed: int) -> optuna.Study:
    """Create the study ``name`` in ``storage``, or continue it when it was started for the same
    task and seed (`InputError` naming ``storage``/``study`` otherwise)."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        rdb = optuna.storages.RDBStorage(storage)
    except Exception as exc:  # SQLAlchemy and drivers raise many types for a bad URL
        raise InputError(f"storage: cannot open {storage!r} ({str(exc).splitlines()[0]})") from None
    directions = [o.direction for o in task.objectives]
    sampler = _sampler(seed, _trials_in(rdb, name))
    try:
        study = optuna.create_study(storage=rdb, study_name=name, directions=directions, sampler=sampler,
                                    load_if_exists=True)
    except ValueError as exc:
        raise InputError(f"study: {name!r} in {storage} cannot be continued ({exc})") from None
    attrs = study.user_attrs
    if _DIGEST not in attrs:
        study.set_user_attr(_DIGEST, task.digest)
        study.set_user_attr(_SEED, seed)
        study.set_user_attr("objectives", [o.label for o in task.objectives])
        study.set_user_attr("task", str(task.path))
    elif attrs[_DIGEST] != task.digest:
        raise InputError(f"study: {name!r} in {storage} was run for another task (or the task, its scene "
                         f"or base robot changed since); give another --study or --out")
    elif attrs[_SEED] != seed:
        raise InputError(f"study: {name!r} in {storage} was started with --seed {attrs[_SEED]}; give that "
                         f"seed, or another --study or --out")
    return study


def _trials_in(storage: optuna.storages.BaseStorage, name: str) -> int:
    """How many trials (any state) the study ``name`` already has in ``storage`` (0: a new study)."""
    try:
        study_id = storage.get_study_id_from_name(name)
    except KeyError:
        return 0
    return len(storage.get_all_trials(study_id, deepcopy=False))


def _sampler(seed: int, trials_so_far: int) -> optuna.samplers.BaseSampler:
    """Seeded multivariate TPE. A continued study draws from a stream of its own (the seed and the
    trials already there), not from the start of the first run's stream again."""
    stream = seed if trials_so_far == 0 else int.from_bytes(
        hashlib.sha256(f"{seed}:{trials_so_far}".encode()).digest()[:4], "little")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(seed=stream, multivariate=True, n_startup_trials=STARTUP_TRIALS)


def finished_trials(study: optuna.Study) -> list[optuna.trial.FrozenTrial]:
    """The study's completed trials, by number."""
    return sorted(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)), key=lambda t: t.number)


def run_study(task: DesignTask, study: optuna.Study, *, trials: int, seed: int = 0, workers: int = 1,
              ray_address: str | None = None, time_limit_s: float | None = None,
              report: Report = _quiet) -> bool:
    """Run trials until the study has ``trials`` finished ones (or, with ``time_limit_s``, an outer
    wall-clock guard, until that long has passed: trials in flight then finish), ``workers`` at a
    time on the executor of `ctrplan.base.parallel.open_pool`. The base design is evaluated first if
    the study has no record of it. Trials in flight when an exception (Ctrl-C) stops the run are
    marked failed. Returns whether the time limit stopped the run before ``trials`` were
    finished."""
    space = distributions(task)
    task_file = str(task.path.resolve())
    deadline = None if time_limit_s is None else time.monotonic() + time_limit_s
    finished = len(finished_trials(study))
    nominal_needed = NOMINAL not in study.user_attrs
    running: dict[int, optuna.Trial | None] = {}  # job number -> trial (None: the base design)
    stopped = False
    with open_pool(workers, ray_address, context=DesignContext) as pool:

        def fill() -> None:
            nonlocal nominal_needed, stopped
            while len(running) < workers:
                if nominal_needed:
                    running[pool.submit(evaluate_job, DesignJob(task_file, {}, seed))] = None
                    nominal_needed = False
                    continue
                asked = sum(t is not None for t in running.values())
                if finished + asked >= trials:
                    return
                if deadline is not None and time.monotonic() >= deadline:
                    stopped = True
                    return
                trial = study.ask(space)
                running[pool.submit(evaluate_job, DesignJob(task_file, trial.params, seed))] = trial

        try:
            fill()
            while running:
                number, record = pool.next_done()
                trial = running.pop(number)
                if trial is None:
                    study.set_user_attr(NOMINAL, record.to_json())
                else:
                    _tell(study, trial, task, record)
                    finished += 1
                report(None if trial is None else trial.number, record, finished)
                fill()
        except BaseException:
            for trial in running.values():
                if trial is not None:
                    study.tell(trial, state=TrialState.FAIL)
            raise
    return stopped


def _tell(study: optuna.Study, trial: optuna.Trial, task: DesignTask, record: DesignRecord) -> None:
    trial.set_user_attr(RECORD, record.to_json())
    for key, value in constraint_values(task, record).items():
        trial.set_constraint(key, value)
    study.tell(trial, [o.value(record) for o in task.objectives])


def ranking_key(record: DesignRecord, objectives: tuple[Objective, ...]) -> tuple[float, ...]:
    """Sort key of a record, best first: the objectives in the task's order (lexicographic)."""
    return tuple(o.rank(record) for o in objectives)


def dominates(a: DesignRecord, b: DesignRecord, objectives: tuple[Objective, ...]) -> bool:
    """Whether record ``a`` is at least as good as ``b`` in every objective and better in one."""
    ka, kb = ranking_key(a, objectives), ranking_key(b, objectives)
    return all(x <= y for x, y in zip(ka, kb, strict=True)) and ka != kb
