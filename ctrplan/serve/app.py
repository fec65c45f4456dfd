"""Start and stop the whole app of `ctrplan serve`: viser on a private port, the page on it, the front
(page and JSON API) on the address asked for. `serving` is what the command and the tests use."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import viser

from ctrplan.serve import api
from ctrplan.serve.front import FrontServer
from ctrplan.serve.page import Page
from ctrplan.serve.session import PlanSession


@dataclass
class App:
    """A running app: its address, the viser server, the page and the session."""

    url: str
    server: viser.ViserServer
    page: Page
    session: PlanSession
    front: FrontServer


@contextlib.contextmanager
def serving(session: PlanSession, scene_file: Path, host: str = "127.0.0.1", port: int = 8080,
            out: Path = Path("runs/serve")) -> Iterator[App]:
    """The app of ``session`` on ``host:port`` (0: a free port) until the block ends; the scene's
    target is planned first. `OSError` when the port cannot be had."""
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints its private address: not ours
        server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    page = front = None
    try:
        page = Page(server, session, out, scene_file)

        def on_change(kind: str, value) -> None:
            if kind == "plan":
                page.show(value, move_target=True)
            else:
                page.show_move(value)
                page.request(session.target.center, session.target.tolerance_mm)

        front = FrontServer(host, port, server.get_port(),
                            lambda method, path, body: api.handle(session, method, path, body, on_change))
        front.start()
        page.request(session.target.center, session.target.tolerance_mm)
        shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
        yield App(f"http://{shown}:{front.port}/", server, page, session, front)
    finally:
        if front is not None:
            front.stop()
        if page is not None:
            page.close()
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
