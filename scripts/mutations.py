"""Apply plausible one-line bugs to the safety- and science-critical code, one at a time, and check
that the tests meant to catch each one fail.

    python scripts/mutations.py            # every mutation (several minutes)
    python scripts/mutations.py --list     # what would be applied
    python scripts/mutations.py tolerance  # those whose name contains "tolerance"

Each mutation replaces one exact piece of source text (it must occur exactly once: a mutation whose
text the code no longer has is reported as stale) and runs its tests with pytest; the file is
restored afterwards, whatever happens. Each run gets a fresh numba cache folder (NUMBA_CACHE_DIR), so
no kernel compiled from a mutated file is reused after the file is restored, and none compiled from
the real file hides a mutation. Exit code 1 when a mutation survived or is stale.

The habit the mutations check: every safety or science function gets a test that a sign, index,
bound or unit error would fail (tests/<package>/, e.g. tests/model/test_target_and_domain_geometry.py,
hold those written for issue 25).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
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


FRAMES = "tests/planning/test_planning_frames.py::test_"
STABILITY = "tests/stability/test_stability_use.py::test_"
BAD = "tests/cli/test_bad_input.py::test_"
PHYSICS = "tests/calibration/test_calibration_physics.py::test_"
GEOMETRY = "tests/model/test_target_and_domain_geometry.py::test_"
SWEEP = "tests/stability/test_sweep_flags.py::test_"
DESIGN = "tests/design/test_design_record.py::test_"
RULES = "tests/calibration/test_selection_rules.py::test_"
FILES = "tests/cli/test_output_folders.py::test_"
ATOMIC = "tests/model/test_dataio.py::test_"
THRESHOLD = "tests/model/test_any_robot.py::test_domain_check_reproduces_the_two_tube_threshold"

MUTATIONS = (
    Mutation("exact validation at the identity pose", "ctrplan/planning/model.py",
             "RobotCollisionChecker(self.world, self.scene.base_pose, self.points,",
             "RobotCollisionChecker(self.world, np.eye(4), self.points,",
             (FRAMES + "validation_checks_the_robot_where_the_base_pose_puts_it",)),
    Mutation("exact validation without the margin", "ctrplan/planning/validate.py",
             "_collisions_and_clearance(report, model.collision_checker(margin), ebb, clearance_stride)",
             "_collisions_and_clearance(report, model.collision_checker(0.0), ebb, clearance_stride)",
             (FRAMES + "validation_keeps_the_margin_and_measures_the_clearance",)),
    Mutation("validation steps bounded by the thickest capsule", "ctrplan/planning/validate.py",
             "bound = float(np.min(ebb.radius_mm)) + margin",
             "bound = float(np.max(ebb.radius_mm)) + margin",
             (FRAMES + "validation_densifies_until_no_point_moves_more_than_the_thinnest_capsule",)),
    Mutation("validation not refined between states", "ctrplan/planning/validate.py",
             "dense, ebb = refine_steps(model.space, exact, dense, ebb, bound)", "pass",
             (FRAMES + "validation_densifies_until_no_point_moves_more_than_the_thinnest_capsule",)),
    Mutation("tip tested against the target in the robot frame", "ctrplan/planning/validate.py",
             "scene.target.contains(tip)", "scene.target.contains(ebb.tip_mm[-1])",
             (FRAMES + "plan_in_a_moved_scene_ends_in_the_target_and_clears_the_obstacles",
              FRAMES + "tip_in_target_is_judged_in_the_scene_frame_with_the_files_tolerance")),
    Mutation("target tolerance doubled", "ctrplan/scene/",
             "return self.normalized_radius(p) <= 1.0 + slack",
             "return self.normalized_radius(p) <= 2.0 + slack",
             (FRAMES + "tip_in_target_is_judged_in_the_scene_frame_with_the_files_tolerance",)),
    Mutation("unstable states not counted as failing", "ctrplan/planning/validate.py",
             "if not (ebb.stable[i] and c.distance_mm > checker.margin_mm):",
             "if not c.distance_mm > checker.margin_mm:",
             (STABILITY + "exact_validation_fails_every_unstable_state",)),
    Mutation("validation reports every path stable", "ctrplan/planning/validate.py",
             "report.stable = bool(ebb.stable.all())", "report.stable = True",
             (STABILITY + "exact_validation_fails_every_unstable_state",)),
    Mutation("the stability decision never checks stability", "ctrplan/planning/model.py",
             "return backend if self.certified else backend.checking_stability()", "return backend",
             (STABILITY + "exact_validation_fails_every_unstable_state",
              STABILITY + "plan_never_uses_a_configuration_that_snaps")),
    Mutation("certificate accepted whatever the fingerprint", "ctrplan/kinematics/stability.py",
             'return doc.get("fingerprint") == robot.fingerprint and doc.get("snap_free") is True',
             'return doc.get("snap_free") is True',
             (STABILITY + "a_certificate_counts_only_for_its_robot_and_a_snap_free_verdict",)),
    Mutation("certificate accepted whatever snap_free says", "ctrplan/kinematics/stability.py",
             'return doc.get("fingerprint") == robot.fingerprint and doc.get("snap_free") is True',
             'return doc.get("fingerprint") == robot.fingerprint',
             (STABILITY + "a_certificate_counts_only_for_its_robot_and_a_snap_free_verdict",)),
    Mutation("stiffness_ratio with nu = E/G - 1", "ctrplan/model/causes/",
             "t.youngs_modulus_mpa / (2.0 * t.shear_modulus_mpa) - 1.0",
             "t.youngs_modulus_mpa / t.shear_modulus_mpa - 1.0",
             (PHYSICS + "stiffness_ratio_is_poissons_ratio_nu_equal_e_over_2g_minus_1",)),
    Mutation("diagnose ignores the Wilcoxon p-value", "ctrplan/calibration/selection.py",
             "bool(gain >= min_gain and p < alpha)", "bool(gain >= min_gain)",
             (PHYSICS + "a_mean_gain_is_not_significant_when_most_rows_get_worse",)),
    Mutation("Poisson limit of the robot loader 5", "ctrplan/model/robot.py",
             "if not -1.0 < poisson <= 0.5:", "if not -1.0 < poisson <= 5:",
             (BAD + "bad_input_fails_cleanly_and_writes_nothing",)),
    Mutation("tube nesting not checked", "ctrplan/model/robot.py",
             "if tubes[i].outer_diameter_mm > tubes[i + 1].inner_diameter_mm:", "if False:",
             (BAD + "bad_input_fails_cleanly_and_writes_nothing",)),
    Mutation("joint domain not checked against the tube lengths", "ctrplan/model/robot.py",
             "        n, L = self.n_tubes, np.asarray(lengths_mm, dtype=float)\n",
             "        return None\n        n, L = self.n_tubes, np.asarray(lengths_mm, dtype=float)\n",
             (BAD + "robot_domain_is_refused_at_load_so_sampling_stays_physical",)),
    Mutation("CSV rows longer than the header accepted", "ctrplan/base/dataio.py",
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
    Mutation("--time-limit 0 accepted", "ctrplan/cli/options.py",
             "if not (math.isfinite(seconds) and seconds > 0):",
             "if not (math.isfinite(seconds) and seconds >= 0):",
             (BAD + "bad_option_fails_cleanly_and_writes_nothing", "tests/cli/test_cli_options.py")),
    Mutation("train leaves its checkpoint", "ctrplan/cli/model.py",
             "    remove_checkpoint(out)  # the run finished: nothing to resume\n", "",
             ("tests/training/test_trainer.py::"
              "test_cli_train_with_a_time_limit_reports_its_last_step_and_leaves_no_checkpoint",)),
    Mutation("train's progress stops at the last multiple of 10 steps", "ctrplan/training/trainer.py",
             "last = self.step == steps or self._out_of_time()", "last = self.step == steps",
             ("tests/training/test_trainer.py::"
              "test_cli_train_with_a_time_limit_reports_its_last_step_and_leaves_no_checkpoint",)),
    Mutation("an interrupt that became another exception leaks a traceback", "ctrplan/cli/__init__.py",
             "if not (console.interrupted() or isinstance(exc, (KeyboardInterrupt, typer.Abort))):",
             "if not isinstance(exc, (KeyboardInterrupt, typer.Abort)):",
             ("tests/cli/test_ctrl_c.py::test_ctrl_c_inside_a_numba_kernel",)),
    # ---- issue 25 §5: bugs nobody listed (the guard tests and the strengthened ones) ----------
    Mutation("ellipsoid target rotation applied transposed", "ctrplan/scene/",
             "return (np.asarray(p, dtype=float) - self.center) @ self.rotation\n",
             "return (np.asarray(p, dtype=float) - self.center) @ self.rotation.T\n",
             (GEOMETRY + "an_oblique_ellipsoid_contains_its_long_axis_and_not_its_mirror_image",)),
    Mutation("ellipsoid target samples rotated transposed", "ctrplan/scene/",
             "return (u * r * self.semi_axes) @ self.rotation.T + self.center",
             "return (u * r * self.semi_axes) @ self.rotation + self.center",
             (GEOMETRY + "an_oblique_ellipsoid_contains_its_long_axis_and_not_its_mirror_image",)),
    Mutation("approach angle sign-agnostic", "ctrplan/scene/",
             "c = (t @ self.direction) / np.maximum(",
             "c = np.abs(t @ self.direction) / np.maximum(",
             (GEOMETRY + "a_tip_arriving_from_the_wrong_side_is_not_in_the_target",)),
    Mutation("exact validation's approach angle sign-agnostic", "ctrplan/planning/validate.py",
             "and angle <= scene.target.angle_tolerance_rad + 1e-12)",
             "and min(angle, np.pi - angle) <= scene.target.angle_tolerance_rad + 1e-12)",
             (GEOMETRY + "a_tip_arriving_from_the_wrong_side_is_not_in_the_target",)),
    Mutation("tube N's base-in-front-of-the-plate check on tube 1", "ctrplan/model/robot.py",
             '(qe[:, n - 1] > 1e-9, f"tube {n} base in front of the plate',
             '(qe[:, 0] > 1e-9, f"tube {n} base in front of the plate',
             (GEOMETRY + "the_outermost_tubes_base_in_front_of_the_plate_is_impossible",)),
    Mutation("domain tube-order check on the upper bound", "ctrplan/model/robot.py",
             "if 0 < c < n and b[0] < 0:", "if 0 < c < n and b[1] < 0:",
             (GEOMETRY + "a_domain_that_reverses_the_tube_order_is_refused",)),
    Mutation("stability jump threshold from the largest move", "ctrplan/kinematics/stability.py",
             "typical = np.nanmedian(moves)", "typical = np.nanmax(moves)",
             (SWEEP + "a_snap_between_two_sweep_steps_is_a_jump",)),
    Mutation("non-converged sweep state not counted unstable", "ctrplan/kinematics/stability.py",
             "unstable = ~converged | ~(stab > 0.0)", "unstable = stab <= 0.0",
             (SWEEP + "a_state_whose_equilibrium_was_not_found_counts_unstable",)),
    Mutation("stability sweep turns a translation", "ctrplan/kinematics/stability.py",
             "    q[:, n + tube] = np.linspace(lo, hi, steps)", "    q[:, tube] = np.linspace(lo, hi, steps)",
             (THRESHOLD,)),
    Mutation("design clearance over the safest target", "ctrplan/design/record.py",
             "return min(reached) if reached else None", "return max(reached) if reached else None",
             (DESIGN + "a_designs_clearance_is_its_worst_targets",)),
    Mutation("design trial starts from the scene's start even where it collides",
             "ctrplan/planning/scene_check.py",
             "return cands[chunk[int(np.argmax(valid))]]", "return cands[order[0]]",
             (DESIGN + "a_design_does_not_start_where_the_scenes_start_collides",)),
    Mutation("infeasible designs kept in the ranking", "ctrplan/design/ranking.py",
             "feasible = [d for d in designs if d.record.feasible]", "feasible = list(designs)",
             ("tests/design/test_design.py::test_over_strained_designs_are_never_best",)),
    Mutation("diagnose's BIC margin with its sign flipped", "ctrplan/calibration/selection.py",
             "ok = held_ok and d_bic < -opt.bic_margin", "ok = held_ok and d_bic < opt.bic_margin",
             (RULES + "a_cause_must_lower_the_bic_by_more_than_the_margin",)),
    Mutation("a better fit within the BIC margin never beats", "ctrplan/calibration/selection.py",
             "if a.fit.bic > b.fit.bic + opt.bic_margin:", "if a.fit.bic > b.fit.bic - opt.bic_margin:",
             (RULES + "a_better_fit_within_the_margin_still_beats_a_worse_one",)),
    Mutation("a cause significant on one split named as stable", "ctrplan/calibration/selection.py",
             "if c.significant_splits() >= need]", "if c.significant]",
             (RULES + "a_cause_significant_on_one_split_is_not_stable",)),
    Mutation("diagnose's gain ratio inverted", "ctrplan/calibration/diagnosis.py",
             "100.0 * (1.0 - ext / nom)", "100.0 * (1.0 - nom / ext)",
             (RULES + "the_reported_gain_is_the_held_out_error_saved",)),
    Mutation("output folder check forgets new parents", "ctrplan/base/dataio.py",
             "missing = [p for p in (path, *path.parents) if not p.exists()]",
             "missing = [p for p in (path,) if not p.exists()]",
             (FILES + "the_output_check_leaves_no_folder_of_a_deep_new_path",
              FILES + "a_command_failing_after_the_output_check_leaves_no_folder")),
    Mutation("atomic write leaves its temporary file on Ctrl-C", "ctrplan/base/dataio.py",
             "    except BaseException:\n        tmp.unlink(missing_ok=True)",
             "    except Exception:\n        tmp.unlink(missing_ok=True)",
             (ATOMIC + "ctrl_c_inside_an_atomic_write_leaves_the_old_file_and_no_temporary",)),
    Mutation("tail metric p99.9 taken at p99", "ctrplan/training/evaluate.py",
             '"p99_9": float(np.percentile(x, 99.9))', '"p99_9": float(np.percentile(x, 99))',
             ("tests/training/test_eval.py::test_metrics_report_the_tail",)),
    Mutation("orientation error is half the rotation angle", "ctrplan/training/evaluate.py",
             "angle = np.degrees(2 * np.arccos(", "angle = np.degrees(np.arccos(",
             ("tests/training/test_eval.py::test_metrics_report_the_tail",)),
)


def run(mutation: Mutation) -> tuple[str, float]:
    """Apply, test, restore; returns the verdict and seconds: "caught" (a test failed), "SURVIVED"
    (all passed), "STALE" (the source text is gone) or "ERROR" (pytest could not run them)."""
    path = REPO / mutation.path
    original = path.read_text()
    if original.count(mutation.old) != 1:
        return "STALE", 0.0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="ctrplan-mutation-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        try:
            path.write_text(original.replace(mutation.old, mutation.new))
            result = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                                     *mutation.tests], cwd=REPO, capture_output=True, text=True, check=False,
                                    env=env)
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
