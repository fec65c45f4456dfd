"""`ctrplan scene ...`: make and check planning scenes."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ctrplan.cli import HELP_SETTINGS, app

SCENE_HELP = "Make and check planning scenes."
scene_app = typer.Typer(help=SCENE_HELP, short_help=SCENE_HELP, no_args_is_help=True,
                        rich_markup_mode=None, context_settings=HELP_SETTINGS)
app.add_typer(scene_app, name="scene")


@scene_app.command("from-labels")
def from_labels(
    labels: Annotated[Path, typer.Argument(metavar="LABELS.nii[.gz]|LABELS.nrrd",
                                           help="Label volume (integer voxels, with its affine).")],
    names: Annotated[Path, typer.Option(
        "--names", metavar="NAMES.yaml",
        help="Label value -> obstacle name, e.g. '3: right_internal_carotid'.")],
    template: Annotated[Path, typer.Option(
        "--template", metavar="SCENE.yaml",
        help="Scene whose robot, base pose, target, start and planner are kept; its frame must be the "
             "volume's world frame (mm).")],
    out: Annotated[Path, typer.Option("--out", metavar="NEW.yaml",
                                      help="The new scene; its meshes go to NEW_meshes/ beside it.")],
) -> None:
    """Turn a segmentation into a scene: one watertight mesh per named label, in world mm.

    Each label named in NAMES.yaml becomes an obstacle mesh placed by the volume's affine (voxel
    spacing, orientation, origin): marching cubes, light smoothing and decimation, within one voxel
    of the segmentation. NEW.yaml is the template with its obstacles replaced by these meshes.
    """
    from ctrplan.scene_labels import scene_from_labels

    console = Console(stderr=True)
    with console.status("meshing labels", spinner="dots") if console.is_terminal else nullcontext():
        scene, volume = scene_from_labels(labels, names, template, out)
    shape = "x".join(str(n) for n in volume.labels.shape)
    spacing = "x".join(f"{v:.3g}" for v in volume.spacing_mm)
    console.print(f"{volume.source}: {shape} voxels of {spacing} mm -> {len(scene.obstacles)} meshes")
    for obstacle in scene.obstacles:
        lo, hi = obstacle.bounds
        console.print(f"  {obstacle.name}: {len(obstacle.faces)} triangles, extent "
                      f"{' x '.join(f'{v:.1f}' for v in hi - lo)} mm")
    console.print(f"wrote {out}")

