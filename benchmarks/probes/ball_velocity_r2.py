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
* ``raw history``: the ball's features of the filter's last ``lag`` frames (no CVA);
* ``history y+u``: the same frames and the learner's last ``lag - 1`` commands: every CVA
  state of that lag is a linear function of them, so no CVA candidate at that lag (any
  order, input scaling or component count) exceeds this row's linear R^2.

The rows above are in-sample least-squares fits (at most 58 regressors on 1,000-2,600
steps). A second table is held out: fitted on the first half of the envs, scored on the
other half. Its ``k-NN on history y+u`` row (10 nearest neighbours, z-scored) says how much
of the velocity the same history holds for a nonlinear map; its other rows say what a
Q-table can tell apart: the velocity predicted by its code's mean, for a k-means codebook
of the ball's state (as many codes as Table 2's ball group, ``cva.quantizer.group_codes``,
fitted on the first half's visible steps of the driving run) of the current features and
of the CVA state, z-scored (Table 2's quantiser) or with each component weighted by its
canonical correlation.

Candidates: ``--set PATH=VALUE`` (repeatable) changes Table 2's config before the ball is
identified (e.g. ``cva.ident.lag_max=6``, ``cva.n_used_objects=12,4,4``,
``cva.collect_steps=10000``).

Only the ball is identified (the goal and the other robot are not needed here), and a
tiny quantiser is fitted (the probe reads the continuous state, not the index).

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/ball_velocity_r2.py [--seed 0] [--envs 64] [--steps 100]
        [--collect-steps N] [--set PATH=VALUE ...] [--out runs/ball_velocity_r2] [--tiny]

Writes ``benchmarks/results/ball_velocity_r2.json``: per invocation (key: the seed, then
the options that differ from their defaults, e.g. ``seed=0``, ``seed=1,
set=cva.collect_steps=10000``) the header's figures (lag, order, the share of steps with
the ball lying still), the steps used and both tables' R^2 (forward, lateral; null for
"-"), and the run's CPU and wall-clock seconds, keeping the entries of other invocations.
``--tiny`` (a smoke test: 8 envs x 40 steps, 600 identification steps) checks that the
probe runs and writes into ``--out`` only; its numbers mean little. Cost: about a minute of
CPU at the defaults, mostly compilation. Cited by docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks.hardware import write_entry  # noqa: E402

RESULT = ROOT / "benchmarks" / "results" / "ball_velocity_r2.json"

#: Rolling: ball speed above this, m/s.
ROLLING = 0.1
STATES = ("current", "CVA", "oracle", "CVA, first 4", "raw history", "history y+u")
#: Neighbours of the k-NN row (a nonlinear regression on ``history y+u``).
KNN = 10
CODE_STATES = ("current", "CVA", "CVA, cancor-weighted")
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


def held_out_r2(pred: np.ndarray, y: np.ndarray) -> np.ndarray:
    """1 - SSE / SST per column of ``y`` for predictions ``pred`` (may be negative); NaN
    with fewer than 2 rows or a column without variance."""
    if len(y) < 2:
        return np.full(y.shape[1], np.nan)
    tot = ((y - y.mean(0)) ** 2).sum(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(tot > 1e-12, 1.0 - ((y - pred) ** 2).sum(0) / tot, np.nan)


def code_r2(idx: np.ndarray, y: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """Held-out R^2 of predicting ``y`` by the mean of its code's ``fit`` rows (a code
    without ``fit`` rows: the mean of all ``fit`` rows), on the rows that are not ``fit``."""
    if fit.sum() < 1:
        return np.full(y.shape[1], np.nan)
    mean = y[fit].mean(0)
    pred = np.tile(mean, (len(y), 1))
    for c in np.unique(idx[fit]):
        pred[idx == c] = y[fit & (idx == c)].mean(0)
    return held_out_r2(pred[~fit], y[~fit])


def knn_r2(x: np.ndarray, y: np.ndarray, fit: np.ndarray, k: int = KNN) -> np.ndarray:
    """Held-out R^2 of the ``k``-nearest-neighbour regression of ``y`` on ``x`` (z-scored by
    the ``fit`` rows), neighbours among the ``fit`` rows, on the rows that are not ``fit``."""
    if fit.sum() < k:
        return np.full(y.shape[1], np.nan)
    mu, sd = x[fit].mean(0), x[fit].std(0)
    z = (x - mu) / np.where(sd > 0, sd, 1.0)
    a, b = z[fit], z[~fit]
    d = (b ** 2).sum(1)[:, None] - 2 * b @ a.T + (a ** 2).sum(1)[None]
    near = np.argpartition(d, k - 1, axis=1)[:, :k]
    return held_out_r2(y[fit][near].mean(1), y[~fit])


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


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--steps", type=int, default=100, help="steps per env")
    ap.add_argument("--collect-steps", type=int, default=None,
                    help="identification steps (default: Table 2's cva.collect_steps)")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="override a path of Table 2's config (repeatable)")
    ap.add_argument("--out", default="runs/ball_velocity_r2",
                    help="--tiny: the folder of the results file")
    ap.add_argument("--tiny", action="store_true",
                    help="smoke-test size: 8 envs x 40 steps, 600 identification steps")
    return ap


def invocation_key(args: argparse.Namespace) -> str:
    """The results file's key of an invocation: the seed, then the options that differ from
    their defaults (``--set`` assignments joined by spaces, in their order)."""
    parts = [f"seed={args.seed}"]
    parts += [f"{k}={v}" for k, v, d in (("envs", args.envs, 64), ("steps", args.steps, 100),
                                         ("collect_steps", args.collect_steps, None)) if v != d]
    if args.set:
        parts.append("set=" + " ".join(args.set))
    return ", ".join(parts)


def _setup(args: argparse.Namespace) -> SimpleNamespace | None:
    """Table 2's config with the ``--set`` overrides, and the ball-only CVA parameters of
    the probe; None (after printing why) for an invalid override."""
    from vbl.engine.config import apply_overrides, parse_assignment
    from vbl.engine.registry import load_script
    from vbl.params import ParamError

    cfg = load_script(ROOT / "experiments" / "table2_shoot_pass.py").EXPERIMENT.default_config
    try:
        cfg = apply_overrides(cfg, [parse_assignment(t, cfg) for t in args.set])
    except ParamError as e:
        print(f"error: {e}")
        return None
    cva = cfg.cva
    ball_codes = int(cva.quantizer.group_codes[list(cva.objects).index("ball")])
    n_ball = cva.n_used_per_object()[list(cva.objects).index("ball")]
    p = cva.replace(state="cva", objects=("ball",), n_used_objects=(n_ball,), extra=(),
                    quantizer=cva.quantizer.replace(method="vq", num_codes=4,
                                                    kmeans_iters=1, group_codes=()))
    if args.collect_steps is not None:
        p = p.replace(collect_steps=args.collect_steps)
    return SimpleNamespace(cva=cva, p=p, ep=cfg.env.replace(task_pass=False), n_ball=n_ball,
                           ball_codes=ball_codes)


def _rollouts(args: argparse.Namespace, s: SimpleNamespace):
    """Identify the ball, then run the shooter still and driving at random: ``(recs, fp)``,
    ``recs[still]`` the steps' records (flattened over envs), ``fp`` the env parameters."""
    from vbl.agents.state_maps import CVAMap
    from vbl.engine.jax_setup import engine_precision
    from vbl.envs.shoot_pass import OBS_SLICES, ShootPassEnv

    p, ep = s.p, s.ep
    env = ShootPassEnv("shoot")
    smap = CVAMap(_WithObs(env), p)
    fenv = smap.env
    ball, vis = OBS_SLICES["ball"], OBS_SLICES["visible"].start  # the ball's flag first
    k_prep, k_run = jax.random.split(jax.random.PRNGKey(args.seed))

    with engine_precision():
        fp = jax.jit(lambda k: smap.env_params(smap.prepare(k, SimpleNamespace(cva=p, env=ep)),
                                               ep))(k_prep)

        def rollout(k, still, fp):
            def one(k):
                k0, ks = jax.random.split(k)
                _, st = fenv.reset(k0, fp)

                def body(st, k):
                    ka, kst = jax.random.split(k)
                    a = jnp.where(still, 0, jax.random.randint(ka, (), 0, env.num_actions))
                    obs, st, *_, info = fenv.step(kst, st, a, fp)
                    sp = st.inner  # HistoryState(ShootPassState)
                    th = sp.world.robots[0, 2]
                    v = sp.world.ball_vel
                    vel = jnp.stack([v[0] * jnp.cos(th) + v[1] * jnp.sin(th),
                                     -v[0] * jnp.sin(th) + v[1] * jnp.cos(th)])
                    y = info["y"]
                    seen = y[vis] > 0.5
                    return st, dict(cva=obs["state"], cur=y[ball], vel=vel, seen=seen,
                                    raw=st.hist_y[0].reshape(-1),
                                    raw_u=st.hist_u[0][1:].reshape(-1),
                                    speed=jnp.linalg.norm(v), touched=sp.touched)

                _, rec = jax.lax.scan(body, st, jax.random.split(ks, args.steps))
                return rec

            return jax.vmap(one)(jax.random.split(k, args.envs))

        run = jax.jit(rollout)
        recs = {}
        for still in (True, False):
            recs[still] = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64).reshape(
                (-1,) + a.shape[2:]), run(k_run, jnp.bool_(still), fp))
    return recs, fp


def phase_masks(recs: dict) -> dict:
    """Per phase, ``(record, mask)``: the run's records and its steps of that phase."""
    masks = {}
    for name in PHASES:
        rec = recs[name == "shooter still"]
        rolling = (rec["speed"] > ROLLING) & (rec["seen"] > 0)
        touched = rec["touched"] > 0
        masks[name] = (rec, rolling & ~touched if name in ("shooter still", "approach")
                       else rolling & touched if name == "after contact" else rolling)
    return masks


def state(rec: dict, kind: str) -> np.ndarray:
    """The state vector ``kind`` (a row of ``STATES``) of every step of ``rec``."""
    if kind == "history y+u":
        return np.concatenate([rec["raw"], rec["raw_u"]], axis=1)
    if kind == "current":
        return rec["cur"]
    if kind == "CVA":
        return rec["cva"]
    if kind == "CVA, first 4":
        return rec["cva"][:, :4]
    if kind == "raw history":
        return rec["raw"]
    return np.concatenate([rec["cur"], rec["vel"] * rec["seen"][:, None]], axis=1)


def _cells(c: np.ndarray, row: list) -> str:
    """A table cell ``forward / lateral`` ("-" for NaN); appends the values (None for NaN)
    to ``row``."""
    row.append([None if np.isnan(v) else round(float(v), 6) for v in c])
    return " / ".join("-" if np.isnan(v) else f"{v:.2f}" for v in c)


def fit_table(recs: dict, masks: dict, n_ball: int) -> dict:
    """Print the in-sample table; return its steps used, dims and R^2 per state and phase."""
    print("| state | " + " | ".join(PHASES) + " |")
    print("|---|" + "---|" * len(PHASES))
    print("| steps used | " + " | ".join(str(int(m.sum())) for _, m in masks.values()) + " |")
    dims = {"current": 4, "CVA": n_ball, "oracle": 6, "CVA, first 4": 4,
            "raw history": recs[False]["raw"].shape[1],
            "history y+u": recs[False]["raw"].shape[1] + recs[False]["raw_u"].shape[1]}
    out = {}
    for kind in STATES:
        vals: list = []
        cells = [_cells(r2(state(rec, kind)[m], rec["vel"][m]), vals) for rec, m in
                 masks.values()]
        out[kind] = dict(zip(PHASES, vals, strict=True))
        print(f"| {kind} ({dims[kind]}) | " + " | ".join(cells) + " |")
    return {"steps_used": {n: int(m.sum()) for n, (_, m) in masks.items()},
            "dims": {k: int(v) for k, v in dims.items()}, "r2": out}


def held_out_table(args: argparse.Namespace, s: SimpleNamespace, recs: dict, masks: dict,
                   fp) -> dict:
    """Print the held-out table (fitted on the first half of the envs, scored on the
    second); return its R^2 per row and phase."""
    from vbl.spaces.quantize import QuantizerParams, fit_quantizer, quantize

    moving = recs[False]
    half = {still: np.arange(len(recs[still]["vel"])) < len(recs[still]["vel"]) // 2
            for still in (True, False)}
    cancor = np.asarray(fp.inner.filters[0].cancor, np.float64)
    weights = {"current": None, "CVA": None, "CVA, cancor-weighted": cancor}
    qp = QuantizerParams(method="vq", num_codes=s.ball_codes,
                         kmeans_iters=s.cva.quantizer.kmeans_iters)
    k_code = jax.random.PRNGKey(args.seed + 1)
    fit_on = (moving["seen"] > 0) & half[False]
    codes = {}
    for kind in CODE_STATES:
        base = "current" if kind == "current" else "CVA"
        qz = fit_quantizer(k_code, state(moving, base)[fit_on], qp, weights=weights[kind])
        codes[kind] = {still: np.asarray(quantize(qz, state(recs[still], base)))
                       for still in (True, False)}
    print(f"Held out (fitted on envs 0-{args.envs // 2 - 1}, scored on the others): R^2 of "
          f"the same velocity (forward / lateral) by a {KNN}-nearest-neighbour regression "
          f"and by the mean of its cell in a {s.ball_codes}-code k-means codebook of the "
          "ball's state:")
    print("| held out | " + " | ".join(PHASES) + " |")
    print("|---|" + "---|" * len(PHASES))
    out = {}
    for kind in ("k-NN on history y+u",) + tuple(f"codes of {c}" for c in CODE_STATES):
        cells, vals = [], []
        for name, (rec, m) in masks.items():
            h = half[name == "shooter still"][m]
            if kind.startswith("k-NN"):
                c = knn_r2(state(rec, "history y+u")[m], rec["vel"][m], h)
            else:
                c = code_r2(codes[kind.removeprefix("codes of ")][name == "shooter still"][m],
                            rec["vel"][m], h)
            cells.append(_cells(c, vals))
        out[kind] = dict(zip(PHASES, vals, strict=True))
        print(f"| {kind} | " + " | ".join(cells) + " |")
    return out


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.tiny:
        args.envs, args.steps, args.collect_steps = 8, 40, 600
    cpu0, wall0 = time.process_time(), time.perf_counter()
    s = _setup(args)
    if s is None:
        return 2
    recs, fp = _rollouts(args, s)
    lag, order = int(fp.inner.filters[0].lag), int(fp.inner.filters[0].n)
    rest = float(np.mean(recs[False]["speed"] <= ROLLING))
    masks = phase_masks(recs)
    print(f"Table 2 shooter, seed {args.seed}: {args.envs} envs x {args.steps} steps per "
          f"phase run; ball CVA lag {lag}, AIC order {order}, {s.n_ball} components kept; "
          f"identification {s.p.collect_steps} steps; overrides: "
          f"{', '.join(args.set) or 'none'}. The ball lies "
          f"still (speed <= {ROLLING} m/s, velocity 0: no R^2) in {rest:.0%} of the driving "
          "run's steps.")
    print("R^2 of the ball's true velocity in the shooter's frame (forward / lateral) on "
          "the steps where the ball is visible and rolling:")
    fits = fit_table(recs, masks, s.n_ball)
    held = held_out_table(args, s, recs, masks, fp)
    entry = {"seed": args.seed, "envs": args.envs, "steps": args.steps, "set": args.set,
             "collect_steps": int(s.p.collect_steps), "lag": lag, "order": order,
             "ball_components": int(s.n_ball), "ball_codes": s.ball_codes,
             "still_share": round(rest, 6), **fits, "held_out": held,
             "cpu_seconds": round(time.process_time() - cpu0, 1),
             "wall_seconds": round(time.perf_counter() - wall0, 1)}
    write_entry(Path(args.out) / RESULT.name if args.tiny else RESULT, invocation_key(args),
                entry)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
