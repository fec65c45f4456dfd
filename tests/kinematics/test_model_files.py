"""The shipped model and model files (issue 10): a model found from an installed package, the user's
models/ first, and the PINN's BLAS thread limit only around its own calls."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import ctrplan
from ctrplan.kinematics.model_file import resolve_model, shipped_models


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
