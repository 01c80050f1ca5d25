"""Probe: the env step of this checkout against the env step of an earlier commit.

What it measures: CPU time per env step (observation consumed, auto-reset, random actions,
default parameters) of both vbl tasks at one batch, for the working tree (or ``--head
REV``) and for ``--base REV`` (exported with ``git archive`` into a temporary folder), in
separate processes that alternate, so both sides see the same machine load. Two ways of
passing the env parameters: ``shared`` (one set for every env, as
``benchmarks/env_throughput.py`` does; a ``lax.cond`` on an unbatched value skips its
branch) and ``batched`` (one set per env, as the engine passes a swept config: every
``lax.cond`` on a parameter becomes a select that computes both branches).

Not an experiment and not a benchmark (``vbl bench`` reads ``benchmarks/*.py`` only). Run
from the repository root:

    python benchmarks/probes/env_step_ab.py --base 97abd1d [--head REV] [--batch 4096]
        [--rounds 2] [--env shooting] [--mode shared] [--tiny]

``--tiny`` (a smoke test: ``shooting`` with shared parameters only, batch 8, 2 steps per
call, 1 round) checks that the probe runs; its timings mean little.

Cost: about 4 CPU-minutes at the defaults (compilation of 8 programs per round). Cited by
docs/world.md ("Random numbers").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENVS = ("shooting", "shoot_pass")
MODES = ("shared", "batched")

#: One process: time one env and one way of passing parameters; prints CPU us per step.
CHILD = r"""
import sys, time
root, envname, mode = sys.argv[1:4]
batch, steps = int(sys.argv[4]), int(sys.argv[5])
sys.path.insert(0, root)
import jax, jax.numpy as jnp, numpy as np
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv
env = ShootingEnv() if envname == "shooting" else ShootPassEnv("shoot")
p = env.default_params
_, st0 = jax.jit(jax.vmap(env.reset, (0, None)))(jax.random.split(jax.random.key(0), batch), p)
axes = 0 if mode == "batched" else None
pp = jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (batch, *np.shape(x))), p) \
    if mode == "batched" else p
def run(st, pp, k):
    def body(c, i):
        st, acc = c
        ks = jax.random.split(jax.random.fold_in(k, i), batch)
        a = jax.random.randint(jax.random.fold_in(k, -i), (batch,), 0, env.num_actions)
        o, st, r, te, tr, info = jax.vmap(env.step, (0, 0, 0, axes))(ks, st, a, pp)
        return (st, acc + o.sum() + r.sum()), None   # every observation consumed
    return jax.lax.scan(body, (st, 0.0), jnp.arange(steps))[0][1]
f = jax.jit(run)
jax.block_until_ready(f(st0, pp, jax.random.key(1)))
best = np.inf
for r in range(3):
    c0 = time.process_time()
    jax.block_until_ready(f(st0, pp, jax.random.key(r + 2)))
    best = min(best, time.process_time() - c0)
print(best / (batch * steps) * 1e6)
"""


def export(rev: str, dest: Path) -> None:
    """The tree of ``rev`` into ``dest`` (``git archive``)."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                          capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=data, check=True)


def cpu_us(root: Path, env: str, mode: str, batch: int, steps: int) -> float:
    out = subprocess.run([sys.executable, "-c", CHILD, str(root), env, mode, str(batch),
                          str(steps)], check=True, capture_output=True, text=True,
                         env={**os.environ, "TF_CPP_MIN_LOG_LEVEL": "3"})
    return float(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="git revision to compare with")
    ap.add_argument("--head", default=None, help="git revision to measure (default: the "
                    "working tree)")
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=100, help="steps per timed call")
    ap.add_argument("--rounds", type=int, default=2, help="alternations of the two sides")
    ap.add_argument("--env", choices=ENVS, action="append",
                    help="env to measure (repeatable; default: both)")
    ap.add_argument("--mode", choices=MODES, action="append",
                    help="way of passing the parameters (repeatable; default: both)")
    ap.add_argument("--tiny", action="store_true", help="smoke-test size: shooting, shared, "
                    "batch 8, 2 steps per call, 1 round")
    args = ap.parse_args(argv)
    if args.tiny:
        args.env, args.mode, args.batch, args.steps, args.rounds = (["shooting"], ["shared"],
                                                                    8, 2, 1)
    rows = [(e, m) for e in args.env or ENVS for m in args.mode or MODES]
    best = {}
    with tempfile.TemporaryDirectory() as tmp:
        base, head = Path(tmp) / "base", Path(tmp) / "head"
        base.mkdir()
        export(args.base, base)
        if args.head is None:
            head = ROOT
        else:
            head.mkdir()
            export(args.head, head)
        for _ in range(args.rounds):
            for env, mode in rows:
                for side, root in (("base", base), ("this", head)):
                    t = cpu_us(root, env, mode, args.batch, args.steps)
                    key = (env, mode, side)
                    best[key] = min(best.get(key, t), t)
    load = os.getloadavg()[0]
    print(f"CPU us per env step, batch {args.batch}, best of {args.rounds} rounds x 3 calls "
          f"(load average {load:.1f} at the end); base = {args.base}, this = "
          f"{args.head or 'the working tree'}")
    print("| env | parameters | base | this | this / base |")
    print("|---|---|---:|---:|---:|")
    for env, mode in rows:
        b, t = best[(env, mode, "base")], best[(env, mode, "this")]
        print(f"| {env} | {mode} | {b:.2f} | {t:.2f} | {t / b:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
