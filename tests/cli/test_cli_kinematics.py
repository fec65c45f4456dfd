"""`ctrplan fk`, `ctrplan shape`, `ctrplan bench kinematics` and the README updater, end to end; and the
new-user pitfalls of `fk`/`shape` (issue 10): --model, streaming in chunks with bounded memory, a
progress bar only on a terminal."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import tracemalloc
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from ctrplan.base.dataio import TIP_NAMES, format_csv, read_table
from ctrplan.cli import kinematics as cli_kinematics
from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import JOINT_NAMES, Robot
from tests.paths import REPO

EXAMPLE = REPO / "examples" / "configs.csv"
FK_COLUMNS = (*JOINT_NAMES, *TIP_NAMES, "converged", "stable")


def run(capsys, *args: str) -> tuple[int, str, str]:
    rc = main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def test_help_and_version(capsys):
    rc, out, _ = run(capsys, "--help")
    assert rc == 0
    for command in ("fk", "shape", "bench"):
        assert command in out
    for args in (["fk", "--help"], ["shape", "--help"], ["bench", "kinematics", "--help"]):
        rc, out, _ = run(capsys, *args)
        assert rc == 0 and "--backend" in out
    rc, out, _ = run(capsys, "--version")
    assert rc == 0 and out.startswith("ctrplan ")


def test_fk_writes_measured_data_format_matching_the_solver(tmp_path, capsys, cosserat):
    out_csv = tmp_path / "tips.csv"
    rc, out, err = run(capsys, "fk", str(EXAMPLE), "-o", str(out_csv))
    assert (rc, out, err) == (0, "", "")
    assert out_csv.read_text().splitlines()[0] == ",".join(FK_COLUMNS)
    table = read_table(out_csv, FK_COLUMNS)
    q = read_table(EXAMPLE, JOINT_NAMES).joints
    np.testing.assert_array_equal(table.joints, q)
    expected = cosserat.forward(q, points=2)
    tips = table.values[:, 6:15].reshape(-1, 3, 3)
    np.testing.assert_allclose(tips, expected.tips_mm, atol=1e-6)
    np.testing.assert_array_equal(table.column("converged"), 1)
    np.testing.assert_array_equal(table.column("stable"), 1)  # the nominal domain is snap-free
    # without -o the same CSV goes to stdout
    rc, out, _ = run(capsys, "fk", str(EXAMPLE))
    assert rc == 0 and out == out_csv.read_text()


def test_fk_reports_non_converged_rows(tmp_path, capsys):
    """A robot with strongly curved outer tubes has configurations the shooting cannot solve, even
    with continuation in the relative rotations (opposed tubes past the snap)."""
    robot_file = tmp_path / "curved.yaml"
    text = resources.files("ctrplan.data").joinpath("nominal.yaml").read_text()
    robot_file.write_text(text.replace("curvature_1_per_m: 12.4", "curvature_1_per_m: 40.0")
                          .replace("curvature_1_per_m: 4.37", "curvature_1_per_m: 30.0"))
    q = np.array([[0, 0, 0, 0, 0, 0],
                  [-37.18, -25.81, -0.51, -0.02, 0.18, 1.8],
                  [-70.08, -57.63, -4.06, 2.64, 0.15, -2.66],
                  [-60.35, -52.29, -1.32, -1.85, 0.16, 3.14],
                  [-46.25, -35.26, -3.06, 0.13, -0.23, -1.34]])
    configs = tmp_path / "configs.csv"
    configs.write_text(format_csv(JOINT_NAMES, q, ["%r"] * 6))
    rc, out, err = run(capsys, "fk", str(configs), "--robot", str(robot_file), "-o",
                       str(tmp_path / "tips.csv"))
    assert rc == 0
    table = read_table(tmp_path / "tips.csv", JOINT_NAMES + ("converged",))
    converged = table.column("converged").astype(bool)
    expected = CosseratBackend(Robot.load(robot_file)).forward(q, points=2).converged
    np.testing.assert_array_equal(converged, expected)
    assert not converged.all(), "these configurations converge now: pick harder ones for this test"
    failed_lines = ", ".join(str(line) for line in table.lines[~converged])
    assert err.strip() == (f"ctrplan: note: {np.count_nonzero(~converged)} of 5 configurations did not "
                           f"converge (rows {failed_lines}); their outputs are NaN")
    rows = [line.split(",") for line in (tmp_path / "tips.csv").read_text().splitlines()[1:]]
    for row, ok in zip(rows, converged, strict=True):
        assert all((cell != "nan") == ok for cell in row[6:15])


def test_fk_outside_domain_only_warns_when_allowed(tmp_path, capsys):
    configs = tmp_path / "configs.csv"
    configs.write_text(",".join(JOINT_NAMES) + "\n-40,-20,-5,0,0,0\n")
    rc, out, err = run(capsys, "fk", str(configs), "--allow-outside-domain")
    assert rc == 0
    assert err.strip().splitlines() == [
        f"ctrplan: warning: {configs}: row 2: outside the snap-free domain: "
        "0 <= beta2 - beta1 <= 15 violated (beta2 - beta1 = 20)"]
    assert out.splitlines()[1].endswith(",1")


def test_shape_long_format_runs_from_plate_to_tip(tmp_path, capsys, cosserat):
    out_csv = tmp_path / "shape.csv"
    rc, _, _ = run(capsys, "shape", str(EXAMPLE), "--points", "7", "-o", str(out_csv))
    assert rc == 0
    assert out_csv.read_text().splitlines()[0] == "row,s,x,y,z"
    shape = read_table(out_csv, ("row", "s", "x", "y", "z"))
    configs = read_table(EXAMPLE, JOINT_NAMES)
    b = len(configs.lines)
    assert len(shape.lines) == 7 * b
    rows = shape.column("row").reshape(b, 7)
    np.testing.assert_array_equal(rows, np.repeat(configs.lines[:, None], 7, axis=1))
    s = shape.column("s").reshape(b, 7)
    l1 = configs.joints[:, 0] + Robot.nominal().lengths_mm[0]
    np.testing.assert_allclose(s[:, 0], 0.0)
    np.testing.assert_allclose(s[:, -1], l1, atol=1e-6)
    assert np.all(np.diff(s, axis=1) > 0)
    xyz = shape.values[:, 2:].reshape(b, 7, 3)
    np.testing.assert_allclose(xyz[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(xyz[:, -1], cosserat.forward(configs.joints, points=2).tip_mm, atol=1e-5)


def test_bench_kinematics_json(tmp_path, capsys):
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    rc, out, _ = run(capsys, "bench", "kinematics", "--backend", "cosserat", "--n", "6",
                     "--points", "20,40", "--seed", "3", "--out", str(tmp_path), "--json")
    assert rc == 0
    doc = json.loads(out)  # stdout holds the JSON document and nothing else
    assert {"cpu", "cores", "python", "numba", "torch"} <= set(doc["machine"])
    keys = [(r["backend"], r["mode"], r["points"]) for r in doc["results"]]
    assert keys == [("cosserat", "cold", 20), ("cosserat", "cold", 40),
                    ("cosserat", "warm", 20), ("cosserat", "warm", 40)]
    for r in doc["results"]:
        assert r["n"] == 6 and r["failures"] == 0
        assert 0 < r["min_ms"] <= r["median_ms"] <= r["p90_ms"] <= r["p99_ms"] <= r["max_ms"]
        assert r["p99_over_median"] >= 1
    cold, warm = doc["results"][0], doc["results"][2]
    assert warm["median_iterations"] < cold["median_iterations"]
    assert json.loads((tmp_path / "results.json").read_text()) == doc
    assert (tmp_path / "kinematics_times.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if affinity is not None:
        assert os.sched_getaffinity(0) == affinity  # pinning to one core is undone afterwards


@pytest.fixture(scope="module")
def update_readme():
    """scripts/update_readme.py, imported as a module."""
    spec = importlib.util.spec_from_file_location("update_readme", REPO / "scripts" / "update_readme.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    yield module
    del sys.modules[spec.name]


def test_update_readme_rewrites_only_its_block(tmp_path, update_readme):
    readme = tmp_path / "README.md"
    readme.write_text("# Title\n\n<!-- bench:kinematics:start -->\nold numbers\n"
                      "<!-- bench:kinematics:end -->\n\ntail\n")
    update_readme.main(["kinematics", "--readme", str(readme), "--backend", "cosserat", "--n", "2",
                               "--points", "20", "--out", str(tmp_path / "bench")])
    text = readme.read_text()
    assert text.startswith("# Title\n\n<!-- bench:kinematics:start -->\n| backend |")
    assert text.endswith("<!-- bench:kinematics:end -->\n\ntail\n")
    assert "old numbers" not in text
    assert "| cosserat | cold | 20 | 2 |" in text and "| cosserat | warm | 20 | 2 |" in text
    assert "Machine: " in text
    assert (f"`ctrplan bench kinematics --backend cosserat --n 2 --points 20 --out {tmp_path / 'bench'} "
            "--json`") in text


def test_update_readme_needs_its_markers(update_readme):
    with pytest.raises(SystemExit, match="bench:kinematics:start"):
        update_readme.replace_block("no markers here", "bench:kinematics", "table")


def write_configs(path: Path, robot, n: int, seed: int = 3) -> np.ndarray:
    q = robot.sample_joints(n, np.random.default_rng(seed))
    rows = "\n".join(",".join(map(repr, r)) for r in q.tolist())
    path.write_text(",".join(JOINT_NAMES) + "\n" + rows + "\n")
    return q


def test_fk_and_shape_take_a_model(tmp_path, capsys):
    tips = {}
    for model in ("pinn_nominal", "pinn_nominal_h100"):
        out = tmp_path / f"{model}.csv"
        rc, _, err = run(capsys, "fk", str(EXAMPLE), "--backend", "pinn", "--model", model, "-o", str(out))
        assert rc == 0, err
        tips[model] = np.loadtxt(out, delimiter=",", skiprows=1)[:, 6:15]
    assert np.isfinite(tips["pinn_nominal"]).all()
    diff = np.abs(tips["pinn_nominal"] - tips["pinn_nominal_h100"]).max()
    assert 0 < diff < 5.0  # two different models of the same robot
    rc, _, err = run(capsys, "shape", str(EXAMPLE), "--backend", "hybrid", "--model", "pinn_nominal_h100",
                     "--points", "5", "-o", str(tmp_path / "s.csv"))
    assert rc == 0, err


@pytest.mark.parametrize(("args", "fragments"), [
    (["--model", "pinn_nominal"], ["--model", "cosserat"]),
    (["--backend", "pinn", "--model", "nowhere"], ["--backend pinn", "nowhere", "not found"]),
])
def test_unusable_model_is_one_line(tmp_path, capsys, args, fragments):
    out = tmp_path / "o.csv"
    rc, stdout, err = run(capsys, "fk", str(EXAMPLE), *args, "-o", str(out))
    assert rc == 2 and stdout == "" and len(err.strip().splitlines()) == 1
    assert all(f in err for f in fragments), err
    assert not out.exists()


def test_shape_streams_in_chunks(tmp_path, capsys, monkeypatch, robot, cosserat):
    monkeypatch.setattr(cli_kinematics, "CHUNK_ROWS", 40)  # 4 configurations per chunk of 10 points
    q = write_configs(tmp_path / "c.csv", robot, 11)
    rc, out, err = run(capsys, "shape", str(tmp_path / "c.csv"), "--points", "10")
    assert rc == 0 and err == ""
    got = np.loadtxt(out.splitlines()[1:], delimiter=",")
    assert out.splitlines()[0] == "row,s,x,y,z" and got.shape == (110, 5)
    np.testing.assert_array_equal(got[:, 0], np.repeat(np.arange(2, 13), 10))
    exact = cosserat.forward(q, 10).positions_mm.reshape(-1, 3)
    np.testing.assert_allclose(got[:, 2:], exact, atol=1e-5)


def test_shape_memory_stays_bounded(tmp_path, capsys, robot):
    write_configs(tmp_path / "c.csv", robot, 3000)
    out = tmp_path / "s.csv"
    assert main(["shape", str(EXAMPLE), "--points", "60", "-o", str(out)]) == 0  # one-time set-up
    tracemalloc.start()
    try:
        rc = main(["shape", str(tmp_path / "c.csv"), "--points", "60", "-o", str(out)])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rc == 0, capsys.readouterr().err
    size = out.stat().st_size
    assert size > 5e6
    # all at once held the (3000, 60, 15) states, every row as Python floats and the whole text
    assert peak < 1.5 * size, (peak, size)


@pytest.mark.parametrize("tty", ["0", "1"])
def test_progress_bar_only_on_a_terminal(tmp_path, capsys, monkeypatch, robot, tty):
    monkeypatch.setenv("TTY_COMPATIBLE", tty)  # rich's switch for "stderr is a terminal"
    write_configs(tmp_path / "c.csv", robot, 50)
    rc, out, err = run(capsys, "fk", str(tmp_path / "c.csv"))
    assert rc == 0 and len(out.splitlines()) == 51  # stdout: the CSV only
    assert ("configurations" in err) == (tty == "1"), err
