"""Probe: how much of the ball's true velocity is in the shooter's state vectors (Table 2).

Table 2's CVA identification for the shooter (its default config: ``cva.collect_steps``
random-action steps, the paper's lag rule, the ball's leading canonical components kept
beyond the AIC order), then ``--envs`` x ``--steps`` fresh steps through the filter. On the
steps where the ball is in the image and rolls faster than 0.1 m/s, a linear
least-squares fit (with intercept) of the ball's true velocity in the shooter's frame
(forward, lateral; m/s) from each state vector; the R^2 of each, by phase:

* ``shooter still``: the shooter stands still (action S) while the world goes on and the
  ball approaches (ego-motion removed);
* ``approach``: the shooter drives at random (as in the identification data); the ball
  was passed and the shooter has not touched it yet;
* ``after contact``: the same run, after the shooter touched the ball;
* ``all rolling``: the same run, every rolling step.

While the ball lies still its velocity is 0 (no variance, no R^2): the header gives the
share of such steps. The state vectors (rows):

* ``current``: the ball's current features (4: centroid x, y, width, height);
* ``CVA``: the ball's CVA state, Table 2's components of the ball (``cva.n_used_objects``);
* ``oracle``: the current features + the ball's true velocity in the shooter's frame,
  zeroed when the ball is not visible (R^2 1 by construction on the visible steps; it
  checks the frame and the phases);
* ``CVA, first 4``: the first 4 of the ball's canonical components (its AIC order);
* ``raw history``: the ball's features of the filter's last ``lag`` frames (no CVA).

Only the ball is identified (the goal and the other robot are not needed here), and a
tiny quantiser is fitted (the probe reads the continuous state, not the index).

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/ball_velocity_r2.py [--seed 0] [--envs 64] [--steps 100]
        [--collect-steps N] [--tiny]

``--tiny`` (a smoke test: 8 envs x 40 steps, 600 identification steps) checks that the
probe runs; its numbers mean little. Cost: about a minute of CPU at the defaults, mostly
compilation. Cited by docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]

#: Rolling: ball speed above this, m/s.
ROLLING = 0.1
STATES = ("current", "CVA", "oracle", "CVA, first 4", "raw history")
PHASES = ("shooter still", "approach", "after contact", "all rolling")


def r2(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """R^2 per column of ``y`` of the least-squares fit ``y ~ [x, 1]``; NaN with fewer
    samples than regressors + 2 or a column without variance."""
    if len(x) < x.shape[1] + 2:
        return np.full(y.shape[1], np.nan)
    a = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    tot = ((y - y.mean(0)) ** 2).sum(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(tot > 1e-12, 1.0 - (res ** 2).sum(0) / tot, np.nan)


class _WithObs:
    """The env with its observation also in ``info["y"]`` (the probe reads the visibility
    flag, which the history filter does not pass on); everything else forwarded."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        return getattr(self._env, name)

    def step(self, key, state, action, params=None):
        obs, st, r, term, trunc, info = self._env.step(key, state, action, params)
        return obs, st, r, term, trunc, {**info, "y": obs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--steps", type=int, default=100, help="steps per env")
    ap.add_argument("--collect-steps", type=int, default=None,
                    help="identification steps (default: Table 2's cva.collect_steps)")
    ap.add_argument("--tiny", action="store_true",
                    help="smoke-test size: 8 envs x 40 steps, 600 identification steps")
    args = ap.parse_args(argv)
    if args.tiny:
        args.envs, args.steps, args.collect_steps = 8, 40, 600

    from vbl.agents.cva_state import make_cva_learner
    from vbl.engine.jax_setup import engine_precision
    from vbl.engine.registry import load_script
    from vbl.envs.shoot_pass import OBS_SLICES, ShootPassEnv

    cfg = load_script(ROOT / "experiments" / "table2_shoot_pass.py").EXPERIMENT.default_config
    cva = cfg.cva
    n_ball = cva.n_used_per_object()[list(cva.objects).index("ball")]
    p = cva.replace(state="cva", objects=("ball",), n_used_objects=(n_ball,), extra=(),
                    quantizer=cva.quantizer.replace(method="vq", num_codes=4,
                                                    kmeans_iters=1, group_codes=()))
    if args.collect_steps is not None:
        p = p.replace(collect_steps=args.collect_steps)
    env = ShootPassEnv("shoot")
    ep = cfg.env.replace(task_pass=False)
    lrn = make_cva_learner(_WithObs(env), p, cfg.q, m=2)
    fenv = lrn.env
    ball, vis = OBS_SLICES["ball"], OBS_SLICES["visible"].start  # the ball's flag first
    k_prep, k_run = jax.random.split(jax.random.PRNGKey(args.seed))

    with engine_precision():
        fp = jax.jit(lambda k: lrn.prepare(k, p, ep))(k_prep)
        lag, order = int(fp.inner.filters[0].lag), int(fp.inner.filters[0].n)

        def rollout(k, still, fp):
            def one(k):
                k0, ks = jax.random.split(k)
                _, st = fenv.reset(k0, fp)

                def body(st, k):
                    ka, kst = jax.random.split(k)
                    a = jnp.where(still, 0, jax.random.randint(ka, (), 0, env.num_actions))
                    obs, st, *_, info = fenv.step(kst, st, a, fp)
                    sp = st.inner.inner  # EpisodeCounts(HistoryState(ShootPassState))
                    th = sp.world.robots[0, 2]
                    v = sp.world.ball_vel
                    vel = jnp.stack([v[0] * jnp.cos(th) + v[1] * jnp.sin(th),
                                     -v[0] * jnp.sin(th) + v[1] * jnp.cos(th)])
                    y = info["y"]
                    seen = y[vis] > 0.5
                    return st, dict(cva=obs["state"], cur=y[ball], vel=vel, seen=seen,
                                    raw=st.inner.hist_y[0].reshape(-1),
                                    speed=jnp.linalg.norm(v), touched=sp.touched)

                _, rec = jax.lax.scan(body, st, jax.random.split(ks, args.steps))
                return rec

            return jax.vmap(one)(jax.random.split(k, args.envs))

        run = jax.jit(rollout)
        recs = {}
        for still in (True, False):
            recs[still] = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64).reshape(
                (-1,) + a.shape[2:]), run(k_run, jnp.bool_(still), fp))

    moving = recs[False]
    rest = float(np.mean(moving["speed"] <= ROLLING))
    masks = {}
    for name in PHASES:
        rec = recs[name == "shooter still"]
        rolling = (rec["speed"] > ROLLING) & (rec["seen"] > 0)
        touched = rec["touched"] > 0
        masks[name] = (rec, rolling & ~touched if name in ("shooter still", "approach")
                       else rolling & touched if name == "after contact" else rolling)

    def state(rec, kind):
        if kind == "current":
            return rec["cur"]
        if kind == "CVA":
            return rec["cva"]
        if kind == "CVA, first 4":
            return rec["cva"][:, :4]
        if kind == "raw history":
            return rec["raw"]
        return np.concatenate([rec["cur"], rec["vel"] * rec["seen"][:, None]], axis=1)

    print(f"Table 2 shooter, seed {args.seed}: {args.envs} envs x {args.steps} steps per "
          f"phase run; ball CVA lag {lag}, AIC order {order}, {n_ball} components kept; "
          f"identification {p.collect_steps} steps. The ball lies still (speed <= "
          f"{ROLLING} m/s, velocity 0: no R^2) in {rest:.0%} of the driving run's steps.")
    print("R^2 of the ball's true velocity in the shooter's frame (forward / lateral) on "
          "the steps where the ball is visible and rolling:")
    print("| state | " + " | ".join(PHASES) + " |")
    print("|---|" + "---|" * len(PHASES))
    print("| steps used | " + " | ".join(str(int(m.sum())) for _, m in masks.values()) + " |")
    dims = {"current": 4, "CVA": n_ball, "oracle": 6, "CVA, first 4": 4,
            "raw history": recs[False]["raw"].shape[1]}
    for kind in STATES:
        cells = []
        for rec, m in masks.values():
            c = r2(state(rec, kind)[m], rec["vel"][m])
            cells.append(" / ".join("-" if np.isnan(v) else f"{v:.2f}" for v in c))
        print(f"| {kind} ({dims[kind]}) | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
