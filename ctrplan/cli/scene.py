"""`ctrplan scene ...`: make and check planning scenes."""

from __future__ import annotations

import os
from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console

from ctrplan.cli.app import HELP_SETTINGS, app
from ctrplan.cli.options import ModelOpt, RobotOpt, json_option, max_states_option, seed_option

SCENE_HELP = "Make and check planning scenes."
scene_app = typer.Typer(help=SCENE_HELP, short_help=SCENE_HELP, no_args_is_help=True,
                        rich_markup_mode=None, context_settings=HELP_SETTINGS)
app.add_typer(scene_app, name="scene")


@scene_app.command("from-labels")
def from_labels(
    labels: Annotated[Path, typer.Argument(
        metavar="LABELS.nii[.gz]|LABELS.nrrd|LABELS.seg.nrrd",
        help="Label volume (integer voxels, with its affine and, for NRRD, its space).")],
    template: Annotated[Path, typer.Option(
        "--template", metavar="SCENE.yaml",
        help="Scene whose robot, base pose, target, start and planner are kept; the meshes are written "
             "in its `anatomy:` frame (RAS if it declares none), with the volume's world origin.")],
    out: Annotated[Path, typer.Option("--out", metavar="NEW.yaml",
                                      help="The new scene; its meshes go to NEW_meshes/ beside it.")],
    names: Annotated[Path | None, typer.Option(
        "--names", metavar="NAMES.yaml", show_default=False,
        help="Label value (or segment name) -> obstacle name, e.g. '3: right_internal_carotid' or "
             "'3: {name: right_internal_carotid, margin_mm: 2}'; optional for a .seg.nrrd, whose "
             "segments are named.")] = None,
    unnamed: Annotated[str, typer.Option(
        "--unnamed", metavar="error|skip|keep",
        help="A label present in the volume that nothing names: an error listing them (default), "
             "skip (left out, with a warning listing them) or keep (named label_<value>).")] = "error",
) -> None:
    """Turn a segmentation into a scene: one watertight mesh per labelled structure, in world mm.

    Every voxel frame is converted to RAS (NIfTI is RAS; an NRRD's `space`, e.g. Slicer's LPS, is
    read and converted; a file whose space is unknown is refused), then to the template's
    `anatomy:` frame. Each structure becomes an obstacle mesh: marching cubes, light smoothing,
    decimation to 20,000 triangles, within one voxel of the segmentation. NEW.yaml is the template
    with its obstacles replaced by these meshes.
    """
    from ctrplan.scene.labels import scene_from_labels

    console = Console(stderr=True, soft_wrap=True, highlight=False)
    with console.status("meshing labels", spinner="dots") if console.is_terminal else nullcontext():
        made = scene_from_labels(labels, names, template, out, unnamed)
    volume = made.volume
    shape = "x".join(str(n) for n in volume.grid_shape)
    spacing = "x".join(f"{v:.3g}" for v in volume.spacing_mm)
    layers = volume.labels.shape[0]
    console.print(f"{volume.source}: {shape} voxels of {spacing} mm"
                  + (f" in {layers} layers" if layers > 1 else "")
                  + f", {volume.space} file -> {len(made.structures)} meshes in {made.frame} (scene frame)")
    for structure, obstacle in zip(made.structures, made.scene.obstacles, strict=True):
        lo, hi = obstacle.bounds
        console.print(f"  {obstacle.name} ({structure.segment.describe(layers)}): {len(obstacle.faces)} "
                      f"triangles, {' x '.join(f'{v:.1f}' for v in hi - lo)} mm from "
                      f"{np.round(lo, 1).tolist()} to {np.round(hi, 1).tolist()}")
    console.print(f"wrote {out}")


@scene_app.command("check")
def check(
    scene_file: Annotated[Path, typer.Argument(metavar="SCENE.yaml", help="The scene to check.")],
    robot: RobotOpt = None,
    fix: Annotated[Path | None, typer.Option(
        "--fix", metavar="OUT.yaml",
        help="Write the scene with the nearest valid start found (or its own, if valid) and the --robot "
             "to OUT.yaml.")] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the reachability samples.")] = 0,
) -> None:
    """Check that a scene is usable before planning: units, target, reach, start.

    Exit 0 with a short summary when it is; otherwise one line per problem and exit 2: obstacles of
    the wrong scale (metres or micrometres against the robot's length), a target inside an obstacle,
    a target no configuration reaches from the base pose (sampled, then inverse kinematics), a start
    outside the domain, in collision (naming what it hits), not converged or unstable -- with the
    nearest valid start found. With --fix, a usable scene, or one whose only problem is its start, is
    written to OUT.yaml with a valid start and the --robot (paths made relative to OUT.yaml) and the
    command exits 0.
    """
    from ctrplan.model.robot import Robot
    from ctrplan.planning.scene_check import check_scene
    from ctrplan.planning.start_fix import reaching_start
    from ctrplan.scene.loader import load_scene

    override = Robot.load(robot) if robot is not None else None
    scene = load_scene(scene_file, check_start=False, robot=override)
    console = Console(stderr=True)
    with console.status("checking the scene", spinner="dots") if console.is_terminal else nullcontext():
        report = check_scene(scene, seed=seed, start_fix=reaching_start)
    for key, fact in report.facts.items():
        typer.echo(f"{key}: {fact}")
    start = scene.start if report.usable else report.fixed_start
    fixable = fix is not None and start is not None and all(p.kind == "start" for p in report.problems)
    for problem in report.problems:
        typer.echo(f"ctrplan: {'fixed' if fixable else 'error'}: {problem.message}", err=True)
    if report.usable:
        typer.echo(f"{scene_file}: usable")
    if fixable:
        write_fixed(scene_file, fix, start, robot)
        typer.echo(f"wrote {fix} with the start {np.asarray(start).round(4).tolist()}")
    if not (report.usable or fixable):
        raise typer.Exit(2)


def write_fixed(scene_file: Path, out: Path, start, robot: str | None) -> None:
    """``scene_file`` with ``start`` (and ``robot``, if given) as OUT.yaml, paths relative to it."""
    from ctrplan.base.dataio import atomic_write, check_output_dir
    from ctrplan.base.yamlio import dump_yaml, load_yaml
    from ctrplan.scene.loader import relocated

    check_output_dir(out.parent, "--fix")
    data = relocated(load_yaml(scene_file), out)
    data["start"] = [round(float(v), 6) for v in start]
    if robot is not None:
        data["robot"] = _robot_ref(robot, out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as fh:
        fh.write(f"# {scene_file} with the start found by `ctrplan scene check --fix`.\n" + dump_yaml(data))


@scene_app.command("place")
def place(
    scene_file: Annotated[Path, typer.Argument(metavar="SCENE.yaml",
                                               help="The scene whose robot is placed.")],
    entry: Annotated[str, typer.Option(
        "--entry", metavar="X,Y,Z",
        help="The point the robot enters through (e.g. the nostril), scene frame, mm.")],
    robot: RobotOpt = None,
    out: Annotated[Path | None, typer.Option(
        "--out", metavar="NEW.yaml", show_default=False,
        help="Write the placed scene here instead of changing SCENE.yaml.")] = None,
    backend: Annotated[str, typer.Option(
        "--backend", metavar="NAME", help="Backend of the verification plans.")] = "cosserat",
    model: ModelOpt = None,
    max_states: max_states_option("Work budget of each verification plan (default: 4 s of the backend's "
                                  "reference rate).") = None,
    seed: seed_option("Seed of the sampled configurations and the verification plans.") = 0,
    as_json: json_option("Print the placement (the chosen pose and start, every verified candidate) "
                         "as JSON.") = False,
) -> None:
    """Find a base pose and a start that enter through --entry and reach the target.

    Configurations of the robot are placed with the tip at the target and the backbone through the
    entry (within 2 mm; base outside, within 35 degrees of the line entry -> target), screened for
    collisions with the scene's margins, refined around the best; each free goal pulled back along its
    insertion gives starts through the entry (the most retracted free one, and the one from which the
    pull-back stays free); the best are planned (exact model by default) until a path is confirmed.
    The chosen base pose and start (and --robot) are written into SCENE.yaml (or --out), the rest of
    the file (comments, other keys) kept; nothing is written when no placement is found, and the reason
    is one line (exit 2).
    """
    import json

    from ctrplan.base.dataio import atomic_write, check_output_dir
    from ctrplan.base.errors import InputError
    from ctrplan.cli.options import check_max_states, load_backend
    from ctrplan.model.robot import Robot
    from ctrplan.planning.placement import place_robot
    from ctrplan.scene.loader import load_scene

    point = _point(entry, "--entry")
    target = out or scene_file
    check_output_dir(target.parent, "--out")
    scene = load_scene(scene_file, check_start=False, robot=Robot.load(robot) if robot is not None else None)
    be = load_backend(backend, scene.robot, model)
    console = Console(stderr=True, soft_wrap=True, highlight=False)
    with console.status("placing the robot", spinner="dots") if console.is_terminal else nullcontext() as s:
        report = place_robot(scene, point, be, seed=seed, max_states=check_max_states(max_states),
                             progress=(lambda text: s.update(text)) if s is not None else lambda _t: None)
    if as_json:
        typer.echo(json.dumps(report.to_json(), indent=2))
    c = report.chosen
    if c is None:
        raise InputError(f"{scene_file}: no placement through the entry {point.tolist()}: {report.reason}")
    text, kept = placed_scene_text(scene_file, target, c.base_pose, c.start, robot)
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(target) as fh:
        fh.write(text)
    counts = report.counts
    console.print(f"placed in {report.time_s:.1f} s: {counts['free_goals']:,} collision-free goals "
                  f"through the entry of {counts['placements']:,} placements, {len(report.verified)} planned")
    console.print(f"base at {np.round(c.base_pose[:3, 3], 2).tolist()} mm, {c.base_distance_mm:.1f} mm "
                  f"from the entry, insertion axis {c.tilt_deg:.1f} deg from the line entry -> target")
    console.print(f"start {np.round(c.start, 4).tolist()}: tip {c.depth_mm:.1f} mm past the entry; "
                  f"verified plan ({report.backend}, {c.plan.states:,} states): path clearance "
                  f"{c.path_clearance_mm:.2f} mm")
    console.print(f"wrote {target}" + ("" if kept else " (its comments were not kept: the file is not in "
                                                        "block style)"))


def _point(text: str, option: str) -> np.ndarray:
    """``X,Y,Z`` (mm) as a point (3,); `InputError` naming ``option`` otherwise."""
    from ctrplan.base.errors import InputError

    try:
        p = np.array([float(v) for v in text.split(",")])
    except ValueError:
        p = np.array([])
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InputError(f"{option}: three numbers X,Y,Z (mm, scene frame), got {text!r}")
    return p


def placed_scene_text(scene_file: Path, out: Path, base_pose: np.ndarray, start,
                      robot: str | None) -> tuple[str, bool]:
    """The text of ``scene_file`` with ``base_pose`` (4x4), ``start`` and ``robot`` (if given) as a file at
    ``out`` says them (paths relative to it), comments kept where the file allows (`with_keys`)."""
    from ctrplan.base.yamlio import load_yaml
    from ctrplan.scene.edit import with_keys
    from ctrplan.scene.loader import relocated

    doc = load_yaml(scene_file)
    changes = {"base_pose": {"position": [round(float(v), 4) for v in base_pose[:3, 3]],
                             "rotation": {"matrix": np.round(base_pose[:3, :3], 9).tolist()}},
               "start": [round(float(v), 6) for v in start]}
    if out.parent.resolve() != scene_file.parent.resolve():
        moved = relocated(doc, out)
        changes |= {k: moved[k] for k in ("robot", "obstacles") if k in moved and moved[k] != doc.data.get(k)}
    if robot is not None:
        changes["robot"] = _robot_ref(robot, out)
    return with_keys(scene_file.read_text(), changes)


def _robot_ref(robot: str, out: Path) -> str:
    """``--robot`` as a scene at ``out`` names it: a built-in name, or the file relative to ``out``."""
    from ctrplan.model.robot import BUILTIN_ROBOTS

    return robot if robot in BUILTIN_ROBOTS else os.path.relpath(Path(robot).resolve(), out.parent.resolve())
