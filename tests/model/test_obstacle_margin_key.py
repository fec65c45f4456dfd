"""The ``margin_mm`` key of a scene obstacle: read for every kind of obstacle (default 0), and a bad
value is one error naming the obstacle's key and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from ctrplan.base.errors import InputError
from ctrplan.scene.loader import load_scene
from tests.paths import SCENES


def with_margins(tmp_path: Path, ball: str, block: str | None = None) -> Path:
    text = (SCENES / "open.yaml").read_text()
    text = text.replace("- name: ball\n", f"- name: ball\n  margin_mm: {ball}\n", 1)
    if block is not None:
        text = text.replace("- name: block\n", f"- name: block\n  margin_mm: {block}\n", 1)
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


def test_margins_are_read_per_obstacle(tmp_path):
    scene = load_scene(with_margins(tmp_path, "2.5"))
    assert {o.name: o.margin_mm for o in scene.obstacles} == {"ball": 2.5, "block": 0.0}


@pytest.mark.parametrize("value", ["-0.5", "nope", ".inf"])
def test_a_bad_margin_names_the_obstacle_key_and_line(tmp_path, value):
    path = with_margins(tmp_path, "1.0", value)
    line = path.read_text().splitlines().index(f"  margin_mm: {value}") + 1
    with pytest.raises(InputError, match=rf"s\.yaml:{line}: obstacles\[1\]\.margin_mm: "
                                         r"(must be >= 0|expected a finite number)") as err:
        load_scene(path)
    assert "\n" not in str(err.value)
