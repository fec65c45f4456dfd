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
from ctrplan.cli.options import RobotOpt

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
    from ctrplan.model.robot import BUILTIN_ROBOTS
    from ctrplan.scene.loader import relocated

    check_output_dir(out.parent, "--fix")
    data = relocated(load_yaml(scene_file), out)
    data["start"] = [round(float(v), 6) for v in start]
    if robot is not None:
        data["robot"] = robot if robot in BUILTIN_ROBOTS else \
            os.path.relpath(Path(robot).resolve(), out.parent.resolve())
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as fh:
        fh.write(f"# {scene_file} with the start found by `ctrplan scene check --fix`.\n" + dump_yaml(data))
