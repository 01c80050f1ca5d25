"""``import vbl`` (and every subpackage) changes no global JAX setting and no environment
variable: a user's brax, optax or flax code runs as it would without vbl."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.engine_helpers import REPO

PROBE = r"""
import json, os, sys
import jax
def snapshot():
    names = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_default_matmul_precision",
             "jax_platforms", "jax_debug_nans", "jax_numpy_dtype_promotion")
    return {"config": {n: str(getattr(jax.config, n)) for n in names},
            "env": dict(os.environ)}
before = snapshot()
import vbl, vbl.world, vbl.vision, vbl.envs, vbl.spaces, vbl.sysid, vbl.agents, vbl.engine
import vbl.cli
after = snapshot()
print(json.dumps({"before": before, "after": after,
                  "zeros": str(jax.numpy.zeros(1).dtype)}))
"""


def test_import_vbl_changes_no_global_setting():
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=REPO, capture_output=True,
                         text=True, timeout=300, check=True).stdout
    r = json.loads(out.strip().splitlines()[-1])
    assert r["after"]["config"] == r["before"]["config"]
    assert r["after"]["env"] == r["before"]["env"]
    assert r["zeros"] == "float32"  # JAX's own default: 64-bit types stay off
