"""Learners sharded over devices run independently: a compiled program holds no cross-device
communication, also where a loop's trip count depends on the data, and gives each learner
the numbers it gets alone."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.engine_helpers import REPO

# A program whose step runs a while loop for a data-dependent number of iterations (a
# learner's own count, as the evaluation loops and the trace update's block loop do),
# compiled by the engine on 2 forced CPU devices.
SCRIPT = """
import jax, jax.numpy as jnp, numpy as np
from vbl.engine.experiment import Program
from vbl.engine.runner import _compiled
from vbl.engine.sharding import learner_sharding, put

def init(key, c):
    return jax.random.randint(key, (), 1, 50)

def step(carry, c):
    def body(s):
        i, acc = s
        return i + 1, acc + jnp.sin(i.astype(jnp.float32))
    n, acc = jax.lax.while_loop(lambda s: s[0] < carry, body, (jnp.int32(0), jnp.float32(0)))
    return carry + 1, {"acc": acc}

prog = Program(init=init, step=step, num_chunks=1)
sh = learner_sharding()
assert len(jax.devices()) == 2
init_fn, step_fn, *_ = _compiled(prog, sh)
keys = put(np.asarray(jax.random.split(jax.random.PRNGKey(0), 8)), sh)
cfg = put(np.zeros(8, np.float32), sh)
carry = init_fn(keys, cfg)
hlo = step_fn.lower(carry, cfg).compile().as_text()
print("COLLECTIVES", sum(hlo.count(op) for op in
                         ("all-reduce", "all-gather", "all-to-all", "collective-permute")))
_, m = step_fn(carry, cfg)
want = [float(np.sum(np.sin(np.arange(int(k), dtype=np.float32)), dtype=np.float32))
        for k in np.asarray(carry)]
print("MAXERR", float(np.max(np.abs(np.asarray(m["acc"]) - want))))
"""


def test_sharded_learners_need_no_collectives():
    """On 2 devices the step of a program with a data-dependent loop compiles without
    all-reduce / all-gather (each device loops for its own learners only) and every
    learner's result equals a NumPy loop of its own count."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    r = subprocess.run([sys.executable, "-c", SCRIPT], cwd=REPO, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    out = dict(line.split() for line in r.stdout.splitlines() if line.startswith(("COLL", "MAX")))
    assert int(out["COLLECTIVES"]) == 0
    assert float(out["MAXERR"]) < 1e-4


def test_init_and_final_run_in_bounded_batches(monkeypatch):
    """With at most 3 learners per batch, init and final of 8 learners (two batches and a
    remainder) give each learner what it gets alone; with 9 learners (three batches) init's
    scratch memory is at most half that of all 9 at once (each learner's init builds
    512 x 512 intermediates)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from vbl.engine import runner
    from vbl.engine.experiment import Program
    from vbl.engine.sharding import learner_sharding, put

    def init(key, c):
        m = jax.random.normal(key, (512, 512)) + c
        return jnp.sum(jnp.tanh(m @ m.T))

    def final(carry, c, key):
        return {"v": carry * 2.0 + jax.random.uniform(key)}

    prog = Program(init=init, step=lambda carry, c: (carry, {}), num_chunks=1, final=final)
    sh = learner_sharding()
    d = len(jax.devices())
    temps = {}
    for batch, n in ((3, 8 * d), (3, 9 * d), (10**6, 9 * d)):
        keys = np.asarray(jax.random.split(jax.random.PRNGKey(0), n))
        cfg = np.linspace(0.0, 1.0, n).astype(np.float32)
        monkeypatch.setattr(runner, "ONCE_LEARNER_BATCH", batch)
        init_fn, _, final_fn, _ = runner._compiled(Program(**vars(prog)), sh)
        k, c = put(keys, sh), put(cfg, sh)
        temps[batch, n] = init_fn.lower(k, c).compile().memory_analysis().temp_size_in_bytes
        carry = np.asarray(init_fn(k, c))
        fin = np.asarray(final_fn(put(carry, sh), c, k)["v"])
        alone = np.array([float(init(jnp.asarray(keys[i]), cfg[i])) for i in range(n)])
        np.testing.assert_allclose(carry, alone, rtol=1e-5)
        want = [float(final(alone[i], cfg[i], jnp.asarray(keys[i]))["v"]) for i in range(n)]
        np.testing.assert_allclose(fin, want, rtol=1e-5)
    assert temps[3, 9 * d] <= 0.5 * temps[10**6, 9 * d]
