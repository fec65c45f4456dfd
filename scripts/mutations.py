"""Apply plausible one-line bugs to the safety- and science-critical code, one at a time, and check
that the tests meant to catch each one fail.

    python scripts/mutations.py            # every mutation (several minutes)
    python scripts/mutations.py --list     # what would be applied
    python scripts/mutations.py tolerance  # those whose name contains "tolerance"

Each mutation replaces one exact piece of source text (it must occur exactly once: a mutation whose
text the code no longer has is reported as stale) and runs its tests with pytest; the file is
restored afterwards, whatever happens. Exit code 1 when a mutation survived or is stale.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


FRAMES = "tests/test_planning_frames.py::test_"
STABILITY = "tests/test_stability_use.py::test_"
BAD = "tests/test_bad_input.py::test_"
PHYSICS = "tests/test_calibration_physics.py::test_"

MUTATIONS = (
    Mutation("exact validation at the identity pose", "ctrplan/planning/validate.py",
             "scene.base_pose,\n                                    points, margin)",
             "np.eye(4),\n                                    points, margin)",
             (FRAMES + "validation_checks_the_robot_where_the_base_pose_puts_it",)),
    Mutation("exact validation without the margin", "ctrplan/planning/validate.py",
             "scene.base_pose,\n                                    points, margin)",
             "scene.base_pose,\n                                    points, 0.0)",
             (FRAMES + "validation_keeps_the_margin_and_measures_the_clearance",)),
    Mutation("validation steps bounded by the thickest capsule", "ctrplan/planning/validate.py",
             "bound = float(np.min(ebb.radius_mm)) + margin",
             "bound = float(np.max(ebb.radius_mm)) + margin",
             (FRAMES + "validation_densifies_until_no_point_moves_more_than_the_thinnest_capsule",)),
    Mutation("validation not refined between states", "ctrplan/planning/validate.py",
             "dense, ebb = refine_steps(space, exact, dense, ebb, bound)", "pass",
             (FRAMES + "validation_densifies_until_no_point_moves_more_than_the_thinnest_capsule",)),
    Mutation("tip tested against the target in the robot frame", "ctrplan/planning/validate.py",
             "scene.target.contains(tip)", "scene.target.contains(ebb.tip_mm[-1])",
             (FRAMES + "plan_in_a_moved_scene_ends_in_the_target_and_clears_the_obstacles",
              FRAMES + "tip_in_target_is_judged_in_the_scene_frame_with_the_files_tolerance")),
    Mutation("target tolerance doubled", "ctrplan/scene.py",
             "return self.normalized_radius(p) <= 1.0 + slack",
             "return self.normalized_radius(p) <= 2.0 + slack",
             (FRAMES + "tip_in_target_is_judged_in_the_scene_frame_with_the_files_tolerance",)),
    Mutation("unstable states not counted as failing", "ctrplan/planning/validate.py",
             "if not ebb.stable[i] or not checker.is_free(", "if not checker.is_free(",
             (STABILITY + "exact_validation_fails_every_unstable_state",)),
    Mutation("validation reports every path stable", "ctrplan/planning/validate.py",
             "report.stable = bool(ebb.stable.all())", "report.stable = True",
             (STABILITY + "exact_validation_fails_every_unstable_state",)),
    Mutation("validation never computes stability", "ctrplan/planning/validate.py",
             "    if not is_certified(scene.robot):\n        exact = exact.checking_stability()\n", "",
             (STABILITY + "exact_validation_fails_every_unstable_state",)),
    Mutation("plan() never checks stability", "ctrplan/planning/planner.py",
             "if not is_certified(scene.robot):  # the planner must never",
             "if False:  # the planner must never",
             (STABILITY + "plan_never_uses_a_configuration_that_snaps",)),
    Mutation("certificate accepted whatever the fingerprint", "ctrplan/stability.py",
             'return doc.get("fingerprint") == robot.fingerprint and doc.get("snap_free") is True',
             'return doc.get("snap_free") is True',
             (STABILITY + "a_certificate_counts_only_for_its_robot_and_a_snap_free_verdict",)),
    Mutation("certificate accepted whatever snap_free says", "ctrplan/stability.py",
             'return doc.get("fingerprint") == robot.fingerprint and doc.get("snap_free") is True',
             'return doc.get("fingerprint") == robot.fingerprint',
             (STABILITY + "a_certificate_counts_only_for_its_robot_and_a_snap_free_verdict",)),
    Mutation("stiffness_ratio with nu = E/G - 1", "ctrplan/calibration/effects.py",
             "t.youngs_modulus_mpa / (2.0 * t.shear_modulus_mpa) - 1.0",
             "t.youngs_modulus_mpa / t.shear_modulus_mpa - 1.0",
             (PHYSICS + "stiffness_ratio_is_poissons_ratio_nu_equal_e_over_2g_minus_1",)),
    Mutation("diagnose ignores the Wilcoxon p-value", "ctrplan/calibration/selection.py",
             "bool(gain >= min_gain and p < alpha)", "bool(gain >= min_gain)",
             (PHYSICS + "a_mean_gain_is_not_significant_when_most_rows_get_worse",)),
    Mutation("Poisson limit of the robot loader 5", "ctrplan/robot.py",
             "if not -1.0 < poisson <= 0.5:", "if not -1.0 < poisson <= 5:",
             (BAD + "bad_input_fails_cleanly_and_writes_nothing",)),
    Mutation("tube nesting not checked", "ctrplan/robot.py",
             "if tubes[i].outer_diameter_mm > tubes[i + 1].inner_diameter_mm:", "if False:",
             (BAD + "bad_input_fails_cleanly_and_writes_nothing",)),
    Mutation("joint domain not checked against the tube lengths", "ctrplan/robot.py",
             "        n, L = self.n_tubes, np.asarray(lengths_mm, dtype=float)\n",
             "        return None\n        n, L = self.n_tubes, np.asarray(lengths_mm, dtype=float)\n",
             (BAD + "robot_domain_is_refused_at_load_so_sampling_stays_physical",)),
    Mutation("CSV rows longer than the header accepted", "ctrplan/dataio.py",
             "if len(cells) != len(names):", "if len(cells) < len(names):",
             (BAD + "bad_input_fails_cleanly_and_writes_nothing",)),
    Mutation("missing PINN falls back to pinn_nominal", "ctrplan/kinematics/model_file.py",
             '    raise InputError(f"no PINN model trained for robot',
             '    return candidates[0]\n    raise InputError(f"no PINN model trained for robot',
             (BAD + "missing_pinn_for_the_robot_in_use_says_so",)),
    Mutation("plan --out checked only after planning", "ctrplan/cli/plan.py",
             "check_output_dir(out)  # created when the outputs are written", "pass",
             (BAD + "bad_option_fails_cleanly_and_writes_nothing",)),
    Mutation("negative seed accepted by stability", "ctrplan/cli/stability.py",
             'typer.Option("--seed", min=0)', 'typer.Option("--seed")',
             (BAD + "bad_option_fails_cleanly_and_writes_nothing",)),
    Mutation("train --time-limit 0 accepted", "ctrplan/cli/model.py",
             "(not math.isfinite(time_limit) or time_limit <= 0)",
             "(not math.isfinite(time_limit) or time_limit < 0)",
             (BAD + "bad_option_fails_cleanly_and_writes_nothing",)),
    Mutation("train leaves its checkpoint", "ctrplan/cli/model.py",
             "    remove_checkpoint(out)  # the run finished: nothing to resume\n", "",
             ("tests/test_newuser_trainer.py::"
              "test_cli_train_with_a_time_limit_reports_its_last_step_and_leaves_no_checkpoint",)),
    Mutation("train's progress stops at the last multiple of 10 steps", "ctrplan/training/trainer.py",
             "last = self.step == steps or self._out_of_time()", "last = self.step == steps",
             ("tests/test_newuser_trainer.py::"
              "test_cli_train_with_a_time_limit_reports_its_last_step_and_leaves_no_checkpoint",)),
    Mutation("an interrupt that became another exception leaks a traceback", "ctrplan/cli/__init__.py",
             "if not (console.interrupted() or isinstance(exc, (KeyboardInterrupt, typer.Abort))):",
             "if not isinstance(exc, (KeyboardInterrupt, typer.Abort)):",
             ("tests/test_ctrl_c.py::test_ctrl_c_inside_a_numba_kernel",)),
)


def run(mutation: Mutation) -> tuple[str, float]:
    """Apply, test, restore; returns the verdict and seconds: "caught" (a test failed), "SURVIVED"
    (all passed), "STALE" (the source text is gone) or "ERROR" (pytest could not run them)."""
    path = REPO / mutation.path
    original = path.read_text()
    if original.count(mutation.old) != 1:
        return "STALE", 0.0
    t0 = time.perf_counter()
    try:
        path.write_text(original.replace(mutation.old, mutation.new))
        result = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                                 *mutation.tests], cwd=REPO, capture_output=True, text=True, check=False)
    finally:
        path.write_text(original)
    verdict = {0: "SURVIVED", 1: "caught"}.get(result.returncode, "ERROR")
    return verdict, time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="run the mutations whose name contains one of these")
    parser.add_argument("--list", action="store_true", help="list the mutations and their tests")
    args = parser.parse_args()
    chosen = [m for m in MUTATIONS if not args.names or any(n in m.name for n in args.names)]
    bad = 0
    for m in chosen:
        if args.list:
            print(f"{m.name}: {m.path}\n    {' '.join(m.tests)}")
            continue
        verdict, seconds = run(m)
        bad += verdict != "caught"
        print(f"{verdict:8s} {m.name} ({seconds:.0f} s): {', '.join(t.split('::')[-1] for t in m.tests)}",
              flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
