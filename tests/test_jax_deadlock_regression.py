"""Regression guard: jax/jaxlib 0.10.0-0.10.2 hang on these CPU machines in exactly this
kernel (vmap over >= 64 data sets, mean removal inside the vmapped function, Cholesky +
triangular solves). Run the batched identification at 256 data sets in a subprocess; a hang
fails loudly instead of stalling CI."""

import subprocess
import sys
import textwrap

TIMEOUT_S = 120

SCRIPT = textwrap.dedent("""
    import numpy as np, jax
    import vbl
    from vbl.sysid import CVAParams, identify
    rng = np.random.default_rng(0)
    u = rng.standard_normal((256, 300, 2))
    y = np.cumsum(rng.standard_normal((256, 300, 2)), axis=1) * 0.1 + u[..., ::-1]
    res = identify(u, y, CVAParams(lag=2))
    jax.block_until_ready(res.model.U)
    assert np.all(np.isfinite(np.asarray(res.aic))), "non-finite AIC"
    print("OK", jax.__version__, int(np.asarray(res.n).sum()))
""")


def test_batched_identification_does_not_hang():
    try:
        out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                             timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired as e:  # pragma: no cover - the regression itself
        raise AssertionError(
            f"batched CVA at 256 data sets did not finish in {TIMEOUT_S} s: the jax/jaxlib "
            "deadlock of 0.10.0-0.10.2 (see pyproject.toml pin) is back") from e
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("OK"), out.stdout
