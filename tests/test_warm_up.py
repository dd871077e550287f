"""Compilation happens before the step loop (issue 24's acceptance, docs/performance.md): the
build's warm-up (hybrid.app.build.warm_up) steps a tiny scene of the run's kinds of body, and the
run's own steps then compile no numba kernel. The default scene's first run compiled the sharing
of spinning flat patches (rigid.patches.share_loads) in its first step, 8 s of its loop; the
shatter scene's, 28 s of kernels (the contact solver without deformable nodes, the patches, a
held body's)."""
import json
import subprocess
import sys

import pytest

PROBE = """
import json, sys
from numba.core.registry import CPUDispatcher
from hybrid import Simulation

def compiled():
    # every kernel of the project's modules loaded so far, with its compiled signatures
    out = {}
    for module in list(sys.modules.values()):
        name = getattr(module, "__name__", "") or ""
        if name.split(".")[0] in ("rigid", "fem", "hybrid"):
            for key, value in list(vars(module).items()):
                if isinstance(value, CPUDispatcher):
                    out[f"{name}.{key}"] = len(value.signatures)
    return out

sim = Simulation.from_toml(sys.argv[1])
before = compiled()
sim.run(until=sim.scene.simulation.duration, progress=False, log=lambda message: None)
after = compiled()
print(json.dumps(sorted(k for k, n in after.items() if n > before.get(k, 0))))
"""


@pytest.mark.parametrize("scene", ["default", "shatter"])
def test_a_built_in_scene_compiles_nothing_in_its_step_loop(tmp_path, scene):
    """In a fresh process (what was compiled or loaded from the cache before is not there).
    ``shatter``: its tile breaks, its fragments meet the supports and each other alone (the
    contact solver's rigid-only kernels) and come to rest (held, stepped as anchored)."""
    done = subprocess.run([sys.executable, "-c", PROBE, scene], capture_output=True, text=True,
                          cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
