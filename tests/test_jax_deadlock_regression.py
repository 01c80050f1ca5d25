"""Regression guard: jax/jaxlib 0.10.0-0.10.2 hang on these CPU machines in exactly this
kernel (vmap over >= 64 data sets, mean removal inside the vmapped function, Cholesky +
triangular solves). Run the batched identification at 256 data sets in a subprocess; a hang
fails loudly instead of stalling CI."""

import subprocess
import sys
import textwrap

TIMEOUT_S = 120
CONCURRENT_TIMEOUT_S = 300   # 30 rounds take ~90 s on a 2-core machine under load ~10

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


CONCURRENT_SVD = textwrap.dedent("""
    import os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    import numpy as np, jax, jax.numpy as jnp
    import vbl
    from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
    from vbl.sysid.linalg import svd_thin
    sh = NamedSharding(Mesh(np.array(jax.devices()), ("b",)), P("b"))

    @jax.jit
    def f(a, b, c):  # three independent batched SVDs on two devices: run concurrently
        s = lambda x: jax.vmap(lambda m: svd_thin(m)[1])(x).sum()
        return s(a) + s(b) + s(c)

    rng = np.random.default_rng(0)
    xs = [jax.device_put(rng.standard_normal((512, 40, 30)), sh) for _ in range(3)]
    for _ in range(30):
        jax.block_until_ready(f(*xs))
    print("OK")
""")


def test_concurrent_batched_svds_do_not_hang():
    """jaxlib's batched CPU SVD blocks a pool thread per call while its pieces wait for the
    pool: with plain ``jnp.linalg.svd`` this script hangs (measured, jax 0.9.2, 2 cores);
    ``vbl.sysid.linalg.svd_thin`` runs a batch matrix by matrix and must finish."""
    try:
        out = subprocess.run([sys.executable, "-c", CONCURRENT_SVD], capture_output=True,
                             text=True, timeout=CONCURRENT_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:  # pragma: no cover - the regression itself
        raise AssertionError(f"concurrent batched SVDs did not finish in {CONCURRENT_TIMEOUT_S} "
                             "s: the "
                             "thread-pool deadlock of the batched CPU SVD is back") from e
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("OK"), out.stdout


def test_svd_thin_batched_equals_numpy():
    import jax
    import numpy as np

    from vbl.sysid.linalg import svd_thin

    x = np.random.default_rng(1).standard_normal((2, 5, 7, 4))
    with jax.enable_x64(True):
        u, s, vh = jax.vmap(jax.vmap(svd_thin))(x)
    s_np = np.linalg.svd(x, compute_uv=False)
    np.testing.assert_allclose(np.asarray(s), s_np, rtol=1e-10)
    rebuilt = np.einsum("abik,abk,abkj->abij", np.asarray(u), np.asarray(s), np.asarray(vh))
    np.testing.assert_allclose(rebuilt, x, atol=1e-10)


def test_eigh_desc_batched_equals_numpy():
    import jax
    import numpy as np

    from vbl.sysid.linalg import eigh_desc

    a = np.random.default_rng(2).standard_normal((2, 5, 6, 6))
    s = a @ np.swapaxes(a, -1, -2)
    with jax.enable_x64(True):
        w, v = jax.vmap(jax.vmap(eigh_desc))(s)
    w_np = np.linalg.eigvalsh(s)[..., ::-1]
    np.testing.assert_allclose(np.asarray(w), w_np, rtol=1e-10)
    assert (np.diff(np.asarray(w), axis=-1) <= 0).all()          # descending
    rebuilt = np.einsum("abik,abk,abjk->abij", np.asarray(v), np.asarray(w), np.asarray(v))
    np.testing.assert_allclose(rebuilt, s, atol=1e-10)
