"""Probe: how much of the ball's true velocity is in the shooter's state vectors (Table 2).

Table 2's CVA identification for the shooter (3,000 random-action steps, the paper's lag
rule with ``logdet_stop`` -100, ``lag_max`` 3, the ball's 8 leading canonical components
kept beyond the AIC order), then ``--envs`` x ``--steps`` fresh steps through the
filter. On the steps where the ball is in the image and rolls faster than 0.1 m/s, a
linear least-squares fit (with intercept) of the ball's true velocity in the shooter's
frame (forward, lateral; m/s) from each state vector; the R^2 of each is printed:

* the current ball features (4: centroid x, y, width, height),
* the last 3 raw frames of them (12),
* the CVA state: the first 4 canonical components (the ball's AIC order) and all 8.

Twice: with the shooter driving at random (as in the identification data), and standing
still (action S) while the world goes on. Only the ball is identified (the goal and the
other robot are not needed here), and a tiny quantiser is fitted (the probe reads the
continuous state, not the index).

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/ball_velocity_r2.py [--seed 0] [--envs 64] [--steps 100]

Cost: about two minutes of CPU, mostly compilation. Cited by
docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def r2(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """R^2 per column of ``y`` of the least-squares fit ``y ~ [x, 1]``."""
    a = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    return 1.0 - (res ** 2).sum(0) / ((y - y.mean(0)) ** 2).sum(0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--steps", type=int, default=100)
    args = ap.parse_args(argv)

    from vbl.agents.cva_state import make_cva_learner
    from vbl.engine.jax_setup import engine_precision
    from vbl.engine.registry import load_script
    from vbl.envs.shoot_pass import ShootPassEnv

    t2 = load_script(ROOT / "experiments" / "table2_shoot_pass.py")
    cfg = t2.EXPERIMENT.default_config
    p = cfg.learner.replace(
        state="cva", objects=("ball",), n_used_objects=(8,), extra=(),
        quantizer=cfg.learner.quantizer.replace(method="vq", num_codes=4, kmeans_iters=1))
    env = ShootPassEnv("shoot")
    ep = cfg.env.replace(task_pass=False)
    lrn = make_cva_learner(env, p, m=2)
    fenv = lrn.env
    key = jax.random.PRNGKey(args.seed)
    k_prep, k_run = jax.random.split(key)

    with engine_precision():
        fp = jax.jit(lambda k: lrn.prepare(k, p, ep))(k_prep)

        def rollout(k, still, fp):
            def one(k):
                k0, ks = jax.random.split(k)
                _, st = fenv.reset(k0, fp)

                def body(st, k):
                    ka, kst = jax.random.split(k)
                    a = jnp.where(still, 0, jax.random.randint(ka, (), 0, env.num_actions))
                    obs, st, *_ = fenv.step(kst, st, a, fp)
                    w = st.inner.inner.world  # EpisodeCounts(HistoryState(env state))
                    th = w.robots[0, 2]
                    v = w.ball_vel
                    vel = jnp.stack([v[0] * jnp.cos(th) + v[1] * jnp.sin(th),
                                     -v[0] * jnp.sin(th) + v[1] * jnp.cos(th)])
                    hy = st.inner.hist_y[0]
                    return st, dict(cva=obs["state"], cur=hy[0], raw3=hy[:3].reshape(-1),
                                    vel=vel, speed=jnp.linalg.norm(v))

                _, rec = jax.lax.scan(body, st, jax.random.split(ks, args.steps))
                return rec

            return jax.vmap(one)(jax.random.split(k, args.envs))

        run = jax.jit(rollout)
        print(f"Table 2 shooter, seed {args.seed}: {args.envs} envs x {args.steps} steps; "
              "R^2 of the ball's true velocity (forward / lateral, shooter frame) from:")
        print("| shooter | steps used | current (4) | 3 raw frames (12) | CVA 4 | CVA 8 |")
        print("|---|---|---|---|---|---|")
        for still in (False, True):
            rec = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64).reshape(
                (-1,) + a.shape[2:]), run(k_run, jnp.bool_(still), fp))
            sel = (rec["cur"][:, 2] > 0) & (rec["speed"] > 0.1)
            y = rec["vel"][sel]
            cols = [r2(rec["cur"][sel], y), r2(rec["raw3"][sel], y),
                    r2(rec["cva"][sel][:, :4], y), r2(rec["cva"][sel], y)]
            txt = " | ".join(f"{c[0]:.2f} / {c[1]:.2f}" for c in cols)
            print(f"| {'standing still' if still else 'random actions'} | {int(sel.sum())} "
                  f"| {txt} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
