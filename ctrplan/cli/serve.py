"""`ctrplan serve`: the plan you can see and steer, a local web app (see `ctrplan.serve`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from ctrplan.base.errors import InputError
from ctrplan.cli.app import app
from ctrplan.cli.options import ModelOpt, load_backend
from ctrplan.cli.plan import PlanBackendOpt, PlanRobotOpt, SceneArg
from ctrplan.kinematics import DEFAULT_PLANNING_BACKEND


@app.command("serve")
def serve_command(
    scene: SceneArg,
    roadmap: Annotated[Path | None, typer.Option(
        "--roadmap", metavar="DIR", show_default=False,
        help="Answer from the roadmap in DIR (`ctrplan roadmap build`), repaired as structures move; "
             "without it every target is planned from scratch (the single-query planner).")] = None,
    robot: PlanRobotOpt = None,
    backend: PlanBackendOpt = DEFAULT_PLANNING_BACKEND,
    model: ModelOpt = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on (the page and the API).")
                    ] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535,
                                      help="Port of the page and the API (0: any free one).")] = 8080,
    out: Annotated[Path, typer.Option(
        "--out", metavar="DIR", help="Where the page's write button puts plan_NNN/ folders (path.json, "
                                     "trajectory.csv, ... as `plan --out`).")] = Path("runs/serve"),
) -> None:
    """Serve a page where the target moves and the path follows, with a JSON API (docs/cli.md).

    The page shows the anatomy, the robot and the target; drag the target (or click a structure's
    surface) and the path is planned again, drawn coloured by clearance with the exact model's
    verdict. Structures can be moved (tissue shift): the roadmap is repaired, not rebuilt. Ctrl-C
    stops the server.
    """
    from rich.console import Console

    from ctrplan.base.dataio import check_output_dir
    from ctrplan.cli.progress import StatusLine
    from ctrplan.model.robot import Robot
    from ctrplan.scene.loader import load_scene
    from ctrplan.serve.session import PlanSession

    check_output_dir(out)
    sc = load_scene(scene, robot=None if robot is None else Robot.load(robot))
    be = load_backend(backend, sc.robot, model)
    err = Console(stderr=True, highlight=False)
    with StatusLine(err, "serve", "loading", timed=True) as status:
        session = PlanSession(sc, be, model, roadmap, progress=status)
    _serve(session, scene, host, port, out)


def _serve(session, scene_file: Path, host: str, port: int, out: Path) -> None:
    """Serve until Ctrl-C (`ctrplan.serve.app.serving`)."""
    from ctrplan.serve.app import serving

    try:
        with serving(session, scene_file, host, port, out) as running:
            typer.echo(f"ctrplan serve: {running.url} (API under /api/; Ctrl-C stops)", err=True)
            while True:
                time.sleep(0.5)
    except OSError as exc:  # the port (the loop itself raises none)
        raise InputError(f"--port: cannot listen on {host}:{port} ({exc.strerror or exc})") from None
