"""Outputs never clobber and never escape (issue 25 §4): writing through a symbolic link keeps the
link, devices and named pipes are written in place, sockets are refused, a model name is never a
path, and sizes whose arrays cannot fit are refused before any work."""

from __future__ import annotations

import os
import socket
import stat
import threading
import tracemalloc
from pathlib import Path

import pytest

from ctrplan.base.dataio import atomic_write
from ctrplan.base.errors import InputError
from ctrplan.base.memory import available_bytes, backbone_bytes, check_fits
from ctrplan.cli.app import main

CONFIGS = "beta1,beta2,beta3,alpha1,alpha2,alpha3\n-20,-10,-5,0.1,0.2,0.3\n-30,-20,-10,1,-1,0.5\n"


@pytest.fixture
def configs(tmp_path) -> Path:
    path = tmp_path / "c.csv"
    path.write_text(CONFIGS)
    return path


def one_line_error(capsys, *words: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ctrplan: error: "), err
    for word in words:
        assert word in err, err
    return err


def test_atomic_write_through_a_link_replaces_the_target_and_keeps_the_link(tmp_path):
    """The temporary file goes beside the target (its folder), not beside the link."""
    (tmp_path / "data").mkdir()
    (tmp_path / "links").mkdir()
    target, link = tmp_path / "data" / "out.csv", tmp_path / "links" / "out.csv"
    target.write_text("old\n")
    link.symlink_to(Path("..") / "data" / "out.csv")
    with atomic_write(link) as fh:
        fh.write("new\n")
    assert link.is_symlink() and os.readlink(link) == str(Path("..") / "data" / "out.csv")
    assert target.read_text() == "new\n"
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["out.csv"]
    assert sorted(p.name for p in (tmp_path / "links").iterdir()) == ["out.csv"]


@pytest.mark.parametrize("command", [["fk"], ["shape", "--points", "3"]])
def test_fk_and_shape_write_through_links_and_dangling_links(command, configs, tmp_path, capsys):
    kept, dangling = tmp_path / "kept.csv", tmp_path / "dangling.csv"
    (tmp_path / "target.csv").write_text("old\n")
    kept.symlink_to("target.csv")
    dangling.symlink_to("new_target.csv")
    for link, target in ((kept, "target.csv"), (dangling, "new_target.csv")):
        assert main([*command, str(configs), "-o", str(link)]) == 0
        assert link.is_symlink() and os.readlink(link) == target
        lines = (tmp_path / target).read_text().splitlines()
        assert lines[0].startswith("beta1" if command == ["fk"] else "row") and len(lines) > 2


def test_fk_streams_into_a_named_pipe(configs, tmp_path):
    """The pipe's reader gets the whole CSV and the pipe stays a pipe (it was replaced by a file)."""
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    got = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_text()), daemon=True)
    reader.start()
    assert main(["fk", str(configs), "-o", str(pipe)]) == 0
    reader.join(timeout=30)
    assert stat.S_ISFIFO(os.lstat(pipe).st_mode)
    lines = got[0].splitlines()
    assert lines[0].startswith("beta1,beta2,beta3") and len(lines) == 3


def test_a_socket_is_refused_in_one_line_and_kept(configs, tmp_path, capsys):
    path = tmp_path / "sock"
    server = socket.socket(socket.AF_UNIX)
    try:
        server.bind(str(path))
        assert main(["shape", str(configs), "-o", str(path)]) == 2
        one_line_error(capsys, str(path), "is a socket")
        assert stat.S_ISSOCK(os.lstat(path).st_mode)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["c.csv", "sock"]
    finally:
        server.close()


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="mknod needs root")
def test_character_devices_are_written_in_place(configs, tmp_path, capsys):
    """Copies of /dev/null (1, 3) and /dev/full (1, 7): the null device swallows the CSV, the full
    one is a one-line error; both stay devices (as root they were replaced by plain files)."""
    null, full = tmp_path / "null", tmp_path / "full"
    os.mknod(null, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    os.mknod(full, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    assert main(["fk", str(configs), "-o", str(null)]) == 0
    assert main(["fk", str(configs), "-o", str(full)]) == 2
    one_line_error(capsys, str(full), "No space left on device")
    assert all(stat.S_ISCHR(os.lstat(p).st_mode) for p in (null, full))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.csv", "full", "null"]


@pytest.mark.parametrize("name", ["../evil", "a/b", "", ".", "..", ".hidden", "x y", "v1.2", "/tmp/x"])
def test_train_name_is_a_name(name, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    assert main(["train", "--name", name, "--steps", "1"]) == 2
    one_line_error(capsys, "--name", "is not a model name")
    assert list(tmp_path.rglob("*")) == [tmp_path / "work"]  # no models/, nothing outside it


def test_check_fits_refuses_one_more_than_it_says_fits():
    each = 10 ** 6
    with pytest.raises(InputError, match=r"--n: .* use at most ([\d,]+)") as info:
        check_fits("--n", 10 ** 12, each, "configurations")
    fits = int(str(info.value).rsplit("at most ", 1)[1].replace(",", ""))
    assert fits * each <= available_bytes() / 2 < (fits + 1) * each
    check_fits("--n", fits, each, "configurations")
    with pytest.raises(InputError):
        check_fits("--n", fits + 1, each, "configurations")


def test_eval_model_memory_estimate_is_not_below_what_it_uses(robot):
    """The estimate `eval-model` refuses sizes with covers the arrays a comparison really holds
    (numpy's allocations, traced)."""
    from ctrplan.cli.eval_model import EVAL_COPIES
    from ctrplan.kinematics.pinn import PinnBackend
    from ctrplan.training.evaluate import compare

    pinn = PinnBackend.load(None, robot)
    compare(pinn, robot, n=5, points=10).metrics()
    n, points = 200, 100
    tracemalloc.start()
    try:
        compare(pinn, robot, n=n, points=points).metrics()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= EVAL_COPIES * n * backbone_bytes(robot.n_tubes, points)


@pytest.mark.parametrize("args, option", [
    (["eval-model", "--n", "1000000000"], "--n"),
    (["eval-model", "--n", "10", "--points", "1000000000"], "--points"),
    (["stability", "--n", "100000000"], "--n"),
    (["stability", "--n", "1", "--steps", "1000000000"], "--steps"),
    (["bench", "kinematics", "--backend", "cosserat", "--n", "1000000000"], "--n"),
    (["bench", "kinematics", "--backend", "cosserat", "--n", "10", "--points", "1000000000"], "--points"),
    (["bench", "kinematics", "--backend", "cosserat", "--n", "10", "--batch", "1000000000"], "--batch"),
    (["train", "--set", "dense_configs=1000000000"], "--set dense_configs"),
])
def test_sizes_that_cannot_fit_are_refused_up_front(args, option, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = [] if args[0] == "train" else ["--out", str(tmp_path / "out")]
    assert main([*args, *out]) == 2
    one_line_error(capsys, f"{option}: ", "of memory", "use at most")
    assert list(tmp_path.iterdir()) == []


def test_shape_points_that_cannot_fit_are_refused(configs, tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert main(["shape", str(configs), "--points", "1000000000", "-o", str(out)]) == 2
    one_line_error(capsys, "--points: ", "of memory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.csv"]
