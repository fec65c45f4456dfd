"""PINN backend: physics losses, training, the shipped model's accuracy, model-file safety, hybrid."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend, make_backend
from ctrplan.kinematics.model_file import save_model
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.training.evaluate import compare
from ctrplan.training.losses import boundary_residual
from ctrplan.training.physics import TubeTensors, rhs
from ctrplan.training.recipes import get_recipe
from ctrplan.training.trainer import train
from tests.paths import REPO


def test_ode_residual_vanishes_on_exact_states(robot, cosserat):
    """d/ds of the exact backbone (finite differences) equals the torch right-hand side of the loss."""
    q = robot.sample_joints(6, rng=21)
    bb = cosserat.forward(q, points=3001)
    tt = TubeTensors.from_robot(robot, dtype=torch.float64)
    f = rhs(torch.tensor(bb.state.reshape(-1, 15)), torch.tensor(bb.s_mm.reshape(-1)),
            torch.tensor(np.repeat(q, 3001, axis=0)), tt).numpy().reshape(6, 3001, 15)
    d = (bb.state[:, 2:] - bb.state[:, :-2]) / (bb.s_mm[:, 2:] - bb.s_mm[:, :-2])[..., None]
    # away from transition points, where the derivative jumps
    breaks = np.concatenate([bb.tube_ends_mm, q[:, :3] + [t.straight_length_mm for t in robot.tubes]], 1)
    s = bb.s_mm[:, 1:-1]
    near = (np.abs(s[:, :, None] - breaks[:, None, :]) < 0.2).any(-1)
    err = np.abs(d - f[:, 1:-1])[~near]
    assert err.max() < 3e-5
    # and a wrong physics (tube 2 not curved) is caught by the same check
    tt_wrong = TubeTensors(**{**tt.__dict__, "kappa": tt.kappa * torch.tensor([1.0, 0.0, 1.0],
                                                                                dtype=torch.float64)})
    f_wrong = rhs(torch.tensor(bb.state.reshape(-1, 15)), torch.tensor(bb.s_mm.reshape(-1)),
                  torch.tensor(np.repeat(q, 3001, axis=0)), tt_wrong).numpy().reshape(6, 3001, 15)
    assert np.abs(d - f_wrong[:, 1:-1])[~near].max() > 1e-3


class ExactNet:
    """Stands in for a network: returns exact Cosserat states at (sigma, q)."""

    def __init__(self, robot, scales):
        self.solver = CosseratBackend(robot)
        self.scales = torch.tensor(scales, dtype=torch.float64)

    def __call__(self, sigma: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        out = [self.solver.forward(qi.numpy(), points=np.array([float(si)])).state[0, 0]
               for si, qi in zip(sigma, q, strict=True)]
        return torch.tensor(np.array(out))


def test_boundary_loss_is_zero_on_exact_boundary_values(robot, pinn):
    q = torch.tensor(robot.sample_joints(10, rng=5))
    tt = TubeTensors.from_robot(robot, dtype=torch.float64)
    exact = ExactNet(robot, pinn.net.scales.numpy())
    per_group = boundary_residual(exact, q, tt)
    assert per_group.shape == (5,)
    assert float(per_group.max()) < 1e-12
    assert float(boundary_residual(pinn.net.double(), q, tt).sum()) > 1e-9  # an approximation is not exact
    pinn.net.float()


def test_short_training_lowers_the_loss(robot, tmp_path):
    recipe = get_recipe("fast", steps=60, dense_configs=300, dense_batch=256, collocation=128, boundary=32)
    calls = []
    train(robot, recipe, tmp_path / "tiny", seed=3,
          progress=lambda step, total, stats: calls.append((step, total, stats["loss"])))
    assert [c[0] for c in calls] == [10, 20, 30, 40, 50, 60]  # every 10 steps, the last one included
    assert calls[-1][:2] == (60, 60)
    assert calls[-1][2] < 0.8 * calls[0][2]
    card = json.loads((tmp_path / "tiny.json").read_text())
    assert card["robot_fingerprint"] == robot.fingerprint and card["steps"] == 60
    assert PinnBackend.load(tmp_path / "tiny", robot).forward(robot.sample_joints(2, rng=1)).converged.all()


def test_shipped_model_meets_accuracy_targets(robot, pinn):
    metrics = compare(pinn, robot, n=30, points=60).metrics()
    assert metrics["backbone_error_pct"]["mean"] <= 0.5
    assert metrics["backbone_error_pct"]["max"] <= 1.5


def test_compiled_inference_matches_torch_network(robot, pinn):
    q = robot.sample_joints(20, rng=8)
    frac = np.random.default_rng(0).uniform(0, 1, (20, 5))
    fast = pinn._evaluate(q, frac)
    with torch.no_grad():
        ref = pinn.net(torch.tensor(frac.reshape(-1), dtype=torch.float32),
                       torch.tensor(np.repeat(q, 5, axis=0), dtype=torch.float32)).numpy()
    np.testing.assert_allclose(fast.reshape(-1, 15), ref, atol=2e-4)


@pytest.fixture(scope="module")
def pinn_every_point(robot, pinn) -> PinnBackend:
    return PinnBackend(robot, pinn.net, pinn.card, nodes=None)


def test_interpolated_backbone_matches_network_at_every_point(robot, pinn, pinn_every_point):
    """Hermite interpolation between the network nodes stays within 0.3 mm of the network evaluated
    at every point (measured with the default 15 nodes: <= 0.26 mm on 2000 configurations); node
    values are the network's, up to float32 rounding (1e-4 mm, rad); a point's value does not depend
    on which other points are asked for (part of a backbone costs part of the network)."""
    q = robot.sample_joints(60, rng=40)
    fast, full = pinn.forward(q, 64), pinn_every_point.forward(q, 64)
    assert pinn.describe()["nodes"] < 64 + 4 and pinn_every_point.describe()["nodes"] is None
    assert np.linalg.norm(fast.positions_mm - full.positions_mm, axis=-1).max() < 0.3
    np.testing.assert_allclose(fast.state[:, 0], full.state[:, 0], atol=1e-4)  # s = 0 is a node
    np.testing.assert_allclose(fast.tips_mm, full.tips_mm, atol=1e-4)
    np.testing.assert_allclose(fast.initial_state, full.initial_state, atol=1e-4)
    np.testing.assert_allclose(fast.residual, full.residual, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(fast.quaternions, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(fast.positions_mm[:, -1], fast.tip_mm, atol=1e-9)  # l1 is a node
    frac = np.linspace(0.0, 1.0, 64)
    for part in (frac[40:], frac[:20], frac[[0, 31, 63]]):
        sub = pinn.forward(q, part)
        np.testing.assert_allclose(sub.state, fast.state[:, np.searchsorted(frac, part)], atol=1e-6)
        np.testing.assert_allclose(sub.tips_mm, fast.tips_mm, atol=1e-6)


def test_network_nodes_include_every_transition_point(robot):
    from ctrplan.kinematics._pinn_infer import node_layout
    from ctrplan.kinematics.cosserat import RodArrays

    rod = RodArrays.of(robot)
    for qi in robot.apply_offset(robot.sample_joints(50, rng=41)):
        nodes, seg_of, *_, end_node = node_layout(qi, 24, rod.lengths, rod.straight, rod.EI)
        assert nodes.shape == (25,) and nodes[0] == 0 and np.all(np.diff(nodes) > 0)
        ends = qi[:3] + rod.lengths
        np.testing.assert_allclose(nodes[end_node], ends, atol=1e-9)
        starts = qi[:3] + rod.straight
        for c in starts[(starts > 0) & (starts < ends[0])]:
            assert np.abs(nodes - c).min() < 1e-9
        assert np.all(np.diff(seg_of) >= 0)
    with pytest.raises(ValueError, match="nodes"):
        PinnBackend(robot, PinnNet(robot), nodes=6)


def test_single_and_batched_calls_agree(robot, pinn):
    q = robot.sample_joints(50, rng=42)  # more than one cache-sized chunk
    batch = pinn.forward(q, 64)
    for i in (0, 23, 49):
        one = pinn.forward(q[i], 64)
        np.testing.assert_allclose(one.state[0], batch.state[i], atol=1e-4)  # float32 rounding
        np.testing.assert_allclose(one.residual[0], batch.residual[i], rtol=1e-3, atol=1e-3)


def test_backbones_compile_once_whoever_calls_them(robot, pinn):
    """Single rows, chunked batches and the planner's body queries reach one compiled `backbones`:
    a literal True or False from another kernel would be another numba type (another compile)."""
    from numba.core.types import Literal

    from ctrplan.kinematics._pinn_infer import backbones

    q = robot.sample_joints(3000, rng=3)
    pinn.forward(q[:1], 20), pinn.forward(q, 20), pinn.body(q[:1], 20), pinn.body(q, 20)
    assert backbones.signatures and not [s for s in backbones.signatures if isinstance(s[-1], Literal)]


def test_blocked_batches_are_the_same_on_any_number_of_threads(robot, pinn):
    """A planner's batched calls run in `ROW_BLOCKS` blocks, in parallel where numba has threads: the
    result must not depend on the threads (a seeded plan is the same everywhere), and it must be the
    backbone that `forward` computes row by row (float32 rounding apart)."""
    import numba

    q = robot.sample_joints(13, rng=5)
    frac = np.linspace(0.5, 1.0, 21)
    threads = numba.get_num_threads()
    try:
        runs = []
        for n in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(n)
            runs.append((pinn.body(q, frac), pinn.tip_and_tangent(q)))
    finally:
        numba.set_num_threads(threads)
    for (body, tips), (body2, tips2) in zip(runs, runs[1:], strict=False):
        np.testing.assert_array_equal(body.positions_mm, body2.positions_mm)
        np.testing.assert_array_equal(tips[0], tips2[0])
    body, (tip, _, ok) = runs[0]
    for i in (0, 6, 12):
        one = pinn.forward(q[i], frac)
        np.testing.assert_allclose(body.positions_mm[i], one.positions_mm[0], atol=1e-4)
        np.testing.assert_allclose(tip[i], one.tip_mm[0], atol=1e-4)
    assert body.usable.all() and ok.all()


def test_pinn_is_exactly_rotation_equivariant(robot, pinn):
    q = robot.sample_joints(5, rng=12)
    q[:, 3:] = np.clip(q[:, 3:], -2.0, 2.0)
    c = 0.9
    a, b = pinn.forward(q, 30), pinn.forward(q + np.r_[0, 0, 0, c, c, c], 30)
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    np.testing.assert_allclose(b.positions_mm, a.positions_mm @ rz.T, atol=1e-3)


def test_tip_jacobian_matches_finite_differences(robot, pinn):
    q = robot.sample_joints(3, rng=2)
    tip, jac, ok = pinn.tip_jacobian(q)
    assert ok.all()
    np.testing.assert_allclose(tip, pinn.forward(q, 2).tip_mm, atol=1e-3)
    h = 1e-2
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        plus, minus = pinn.forward(q + dq, 2, check=False), pinn.forward(q - dq, 2, check=False)
        fd = (plus.tip_mm - minus.tip_mm) / (2 * h)
        np.testing.assert_allclose(jac[:, :, j], fd, atol=2e-2 * max(1.0, np.abs(fd).max()))


def test_hybrid_is_exact_and_needs_fewer_iterations(robot, cosserat):
    q = robot.sample_joints(40, rng=30)
    hybrid = make_backend("hybrid", robot)
    h, c = hybrid.forward(q, 20), cosserat.forward(q, 20)
    assert h.converged.all() and h.backend == "hybrid"
    np.testing.assert_allclose(h.positions_mm, c.positions_mm, atol=1e-6)
    assert np.median(h.iterations) < np.median(c.iterations)


@pytest.fixture()
def model_copy(tmp_path, pinn):
    from ctrplan.kinematics.model_file import resolve_model

    src = resolve_model(pinn.card["weights_file"])
    for ext in (".safetensors", ".json"):
        shutil.copy(src.with_suffix(ext), tmp_path / f"m{ext}")
    return tmp_path / "m"


def test_tampered_weights_are_rejected(robot, model_copy):
    data = bytearray(model_copy.with_suffix(".safetensors").read_bytes())
    data[-10] ^= 0xFF
    model_copy.with_suffix(".safetensors").write_bytes(bytes(data))
    with pytest.raises(InputError, match="SHA-256"):
        PinnBackend.load(model_copy, robot)


def test_truncated_weights_with_matching_card_are_rejected(robot, model_copy):
    from ctrplan.kinematics.model_file import file_sha256

    w = model_copy.with_suffix(".safetensors")
    w.write_bytes(w.read_bytes()[:1000])
    card = json.loads(model_copy.with_suffix(".json").read_text())
    card["weights_sha256"] = file_sha256(w)
    model_copy.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(InputError, match="corrupted"):
        PinnBackend.load(model_copy, robot)


def test_model_for_another_robot_is_rejected(robot, model_copy):
    tubes = list(robot.tubes)
    tubes[1] = tubes[1].__class__(**{**tubes[1].__dict__, "curvature_per_mm": 0.0130})
    other = robot.with_changes(tubes=tuple(tubes), name="bent")
    with pytest.raises(InputError, match="trained for robot"):
        PinnBackend.load(model_copy, other)


def test_missing_card_and_missing_model_are_clear(robot, model_copy, tmp_path):
    model_copy.with_suffix(".json").unlink()
    with pytest.raises(InputError, match="model card not found"):
        PinnBackend.load(model_copy, robot)
    with pytest.raises(InputError, match="not found"):
        PinnBackend.load(tmp_path / "nothing", robot)


def test_save_model_round_trip(robot, tmp_path):
    net = PinnNet(robot)
    save_model(net, robot, tmp_path / "fresh", {"recipe": {"name": "none"}})
    loaded = PinnBackend.load(tmp_path / "fresh", robot)
    q = robot.sample_joints(2, rng=0)
    with torch.no_grad():
        a = net(torch.full((2,), 0.5), torch.tensor(q, dtype=torch.float32))
        b = loaded.net(torch.full((2,), 0.5), torch.tensor(q, dtype=torch.float32))
    torch.testing.assert_close(a, b)


def test_training_resumes_from_checkpoint(robot, tmp_path):
    recipe = get_recipe("fast", steps=40, dense_configs=200, dense_batch=128, collocation=64, boundary=16)
    train(robot, recipe, tmp_path / "r", seed=4, time_limit_s=0.0)  # stops at once, leaves a checkpoint
    meta = json.loads((tmp_path / "r.ckpt.json").read_text())
    assert meta["step"] == 0
    done = train(robot, recipe, tmp_path / "r", seed=4, resume=True)
    assert done.steps == 40
    with pytest.raises(InputError, match="another recipe or seed"):
        train(robot, recipe, tmp_path / "r", seed=5, resume=True)


@pytest.mark.parametrize("backend", ["pinn", "hybrid"])
def test_fk_cli_accepts_learned_backends(backend, tmp_path):
    from ctrplan.cli.app import main

    configs = REPO / "examples" / "configs.csv"
    out = tmp_path / "tips.csv"
    assert main(["fk", str(configs), "--backend", backend, "-o", str(out)]) == 0
    rows = out.read_text().strip().splitlines()
    assert rows[0].endswith("converged,stable") and len(rows) > 2
    stable = "nan" if backend == "pinn" else "1"  # only the exact solver can tell stability
    assert all(r.endswith(f",1,{stable}") for r in rows[1:])


@pytest.mark.parametrize("setting", ["nope=1", "dense_batch", "steps=5", "name=fast"])
def test_train_rejects_bad_recipe_overrides(setting, capsys):
    from ctrplan.cli.app import main

    assert main(["train", "--steps", "1", "--set", setting]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ctrplan: error: --set:")


def test_saved_model_files_have_normal_permissions(robot, tmp_path):
    import os

    save_model(PinnNet(robot), robot, tmp_path / "perm", {"recipe": {"name": "none"}})
    plain = tmp_path / "plain"
    plain.write_text("")
    for ext in (".safetensors", ".json"):
        assert os.stat(tmp_path / f"perm{ext}").st_mode == os.stat(plain).st_mode


def test_tip_and_tangent_is_the_backbone_tip(robot, pinn, cosserat):
    """The PINN's one-row tip (inverse kinematics) is the tip of its backbones; the tangent is the
    third column of the tip rotation (`quaternion_to_matrix`, written apart)."""
    from ctrplan.kinematics.backbone import quaternion_to_matrix

    q = robot.sample_joints(40, rng=42)
    for backend in (pinn, cosserat):
        tip, tangent, ok = backend.tip_and_tangent(q)
        bb = backend.forward(q, 2)
        assert ok.all()
        np.testing.assert_allclose(tip, bb.tip_mm, atol=1e-4)
        np.testing.assert_allclose(tangent, quaternion_to_matrix(bb.quaternions[:, -1])[:, :, 2], atol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(tangent, axis=1), 1.0, atol=1e-5)
