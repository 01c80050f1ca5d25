"""vbl.sysid computes in float64 by itself: the same numbers with jax_enable_x64 on or off.

The identification runs once in this process with 64-bit types on (``jax.enable_x64``) and
once in a subprocess with them off (``JAX_ENABLE_X64=0`` and the flag reset after
``import vbl``); the results must be equal.
"""

import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference.sysid_systems import simulate_batch

from vbl.sysid import CVAParams, aic, fit_one, identify

FIELDS = ("lag", "n", "logdet_R", "aic", "aic_curve", "logdet_curve", "cancor")
P64 = CVAParams(lag=2)
P32 = CVAParams(lag=2, dtype="float32")

SCRIPT = textwrap.dedent("""
    import sys
    import numpy as np
    import vbl
    import jax
    jax.config.update("jax_enable_x64", False)
    import jax.numpy as jnp
    from vbl.sysid import CVAParams, aic, fit_one, identify
    assert not jax.config.jax_enable_x64
    d = np.load(sys.argv[1])
    out = {}
    for tag, p in (("d", CVAParams()), ("p64", CVAParams(lag=2)),
                   ("p32", CVAParams(lag=2, dtype="float32"))):
        res = identify(d["u"], d["y"], p)
        for f in %(fields)r:
            out[f"{tag}_{f}"] = np.asarray(getattr(res, f))
        out[f"{tag}_A"] = np.asarray(res.model.A)
    # fit_one inside a caller's jit(vmap) (float32 data, as the CVA learner passes it)
    f = jax.jit(jax.vmap(lambda u, y: fit_one(u, y, CVAParams(lag=2), lag=2, horizon=4,
                                              n_cap=8).logdet))
    out["jit_logdet"] = np.asarray(f(jnp.asarray(d["u"], jnp.float32),
                                     jnp.asarray(d["y"], jnp.float32)))
    out["aic"] = np.asarray(aic(np.float64(-0.123456789), 3, 997, 2, 2))
    assert out["jit_logdet"].dtype == np.float64, out["jit_logdet"].dtype
    np.savez(sys.argv[2], **out)
    print("OK")
""") % {"fields": FIELDS}


def _in_process(u, y) -> dict:
    out = {}
    for tag, p in (("d", CVAParams()), ("p64", P64), ("p32", P32)):
        res = identify(u, y, p)
        for f in FIELDS:
            out[f"{tag}_{f}"] = np.asarray(getattr(res, f))
        out[f"{tag}_A"] = np.asarray(res.model.A)
    f = jax.jit(jax.vmap(lambda a, b: fit_one(a, b, P64, lag=2, horizon=4, n_cap=8).logdet))
    out["jit_logdet"] = np.asarray(f(jnp.asarray(u, jnp.float32), jnp.asarray(y, jnp.float32)))
    out["aic"] = np.asarray(aic(np.float64(-0.123456789), 3, 997, 2, 2))
    return out


@pytest.mark.slow  # 16 s: identification compiled twice (x64 on and off)
def test_identify_same_numbers_with_x64_off(tmp_path):
    rng = np.random.default_rng(3)
    u, y, _ = simulate_batch(rng, np.array([1, 3, 5]), 400, 2, 2, noise=0.05,
                             min_separation=0.15)
    np.savez(tmp_path / "data.npz", u=u, y=y)
    env = {**__import__("os").environ, "JAX_ENABLE_X64": "0"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "data.npz"),
                           str(tmp_path / "off.npz")], capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.startswith("OK"), proc.stderr[-3000:]
    off = dict(np.load(tmp_path / "off.npz"))
    with jax.enable_x64(True):
        on = _in_process(u, y)
    assert set(on) == set(off)
    for k in on:
        assert on[k].dtype == off[k].dtype, (k, on[k].dtype, off[k].dtype)
        np.testing.assert_array_equal(off[k], on[k], err_msg=k)
    assert on["d_aic"].dtype == np.float64 and on["p64_cancor"].dtype == np.float64
