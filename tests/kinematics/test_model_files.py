"""New-user pitfalls of `fk`/`shape` and the shipped model (issue 10): --model, a model found from an
installed package, streaming in chunks with bounded memory, a progress bar only on a terminal."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import ctrplan
from ctrplan.cli import kinematics as cli_kinematics
from ctrplan.cli import main
from ctrplan.kinematics.model_file import resolve_model, shipped_models
from ctrplan.robot import JOINT_NAMES
from tests.paths import REPO

EXAMPLE = REPO / "examples" / "configs.csv"


def run(capsys, *args: str) -> tuple[int, str, str]:
    rc = main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def write_configs(path: Path, robot, n: int, seed: int = 3) -> np.ndarray:
    q = robot.sample_joints(n, np.random.default_rng(seed))
    rows = "\n".join(",".join(map(repr, r)) for r in q.tolist())
    path.write_text(",".join(JOINT_NAMES) + "\n" + rows + "\n")
    return q


def test_shipped_model_lives_in_the_package_and_is_found_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no models/ here
    package = Path(ctrplan.__file__).resolve().parent
    for name in (None, "pinn_nominal", "pinn_nominal_h100", "pinn_two_tube"):
        weights = resolve_model(name)
        assert weights.exists() and package in weights.resolve().parents
    assert shipped_models() == ["pinn_nominal", "pinn_nominal_h100", "pinn_two_tube"]


def test_users_models_dir_comes_first(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "pinn_nominal.safetensors").write_bytes(b"")
    assert resolve_model("pinn_nominal") == Path("models/pinn_nominal.safetensors")


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


def test_pinn_limits_blas_threads_only_around_its_own_calls(robot):
    from threadpoolctl import threadpool_info, threadpool_limits

    from ctrplan.kinematics.pinn import PinnBackend

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    from ctrplan.kinematics.blas import one_blas_thread, single_threaded_blas

    with threadpool_limits(limits=2, user_api="blas"):
        pinn = PinnBackend.load(None, robot)
        pinn.forward(robot.sample_joints(3, np.random.default_rng(0)), 10)
        assert blas_threads() and set(blas_threads()) == {2}  # the process keeps its setting
        with one_blas_thread():
            assert set(blas_threads()) == {1}
        assert set(blas_threads()) == {2}
        with single_threaded_blas():  # a planner's search: one thread throughout, guards inside free
            assert set(blas_threads()) == {1}
            with one_blas_thread():
                assert set(blas_threads()) == {1}
            pinn.forward(robot.sample_joints(3, np.random.default_rng(0)), 10)
            assert set(blas_threads()) == {1}
        assert set(blas_threads()) == {2}
