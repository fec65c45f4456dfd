"""`compile_kernels` compiles (or loads from numba's cache) every kernel a search's checks use, so that
a plan's clock starts after them: on a cold cache a README first plan once spent its whole 10-s time
limit compiling the collision kernels inside the clock and stopped with no state searched. Checked in
a fresh interpreter (in this one earlier tests have compiled everything already): no numba dispatcher
of ctrplan gains a signature when a new checker checks states, batches and edges after it."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from tests.paths import REPO, SCENES

SCRIPT = f"""
import json, sys
import numpy as np
from numba.core.dispatcher import Dispatcher
from ctrplan.planning import ConfigurationChecker, PlanningModel, compile_kernels
from ctrplan.planning.planner import resolve_backend
from ctrplan.scene.loader import load_scene

def signatures():
    return {{f"{{m}}.{{k}}": len(v.signatures) for m, mod in list(sys.modules.items())
            if m.startswith("ctrplan") for k, v in list(vars(mod).items()) if isinstance(v, Dispatcher)}}

scene = load_scene({str(SCENES / "open.yaml")!r})
model = PlanningModel.build(scene, resolve_backend("pinn", scene.robot))
compile_kernels(model)
before = signatures()
checker = ConfigurationChecker(model)
q = model.space.sample(16, np.random.default_rng(0))
checker.is_valid(q[0]); checker.check(q[1:9]); checker.check_motion(q[0], q[9], 0.5)
after = signatures()
new = {{k: v for k, v in after.items() if v != before.get(k, 0)}}
print(json.dumps({{"kernels": len(before), "new": new}}))
"""


def test_a_search_compiles_nothing_after_compile_kernels():
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["kernels"] > 10          # the collision, broadphase and kinematics kernels were seen
    assert doc["new"] == {}, doc["new"]
