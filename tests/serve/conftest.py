"""Fixtures of the `ctrplan serve` tests: a small roadmap of open.yaml (built here, indexed by the
build) and the app serving it on a free port of this machine."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import pytest

from tests.roadmaps import OPEN, small_roadmap


@pytest.fixture(scope="session")
def open_roadmap(tmp_path_factory):
    """A 300-node roadmap of open.yaml with its sweep index (a budget in work: the same every run)."""
    folder = tmp_path_factory.mktemp("serve_roadmap")
    small_roadmap(folder, 2, 300)
    return folder


@pytest.fixture
def app(open_roadmap, tmp_path):
    """The app on open.yaml's roadmap at a free port, the scene's target planned first."""
    from ctrplan.kinematics import make_backend
    from ctrplan.scene.loader import load_scene
    from ctrplan.serve.app import serving
    from ctrplan.serve.session import PlanSession

    sc = load_scene(OPEN)
    session = PlanSession(sc, make_backend("pinn", sc.robot), None, open_roadmap)
    with serving(session, OPEN, "127.0.0.1", 0, tmp_path / "out") as running:
        yield running


def call(url: str, method: str = "GET", body: bytes | dict | None = None) -> tuple[int, dict]:
    """(HTTP status, JSON document) of one request to the app."""
    data = json.dumps(body).encode() if isinstance(body, dict) else body
    request = urllib.request.Request(url, data=data, method=method)
    try:
        with urllib.request.urlopen(request, timeout=120) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())
