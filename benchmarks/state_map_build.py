"""Build time of Figure 5's action-based state map: vbl's cells vs NumPy.

Data: Figure 5's collection (shooting env, 9 primitives x ``episodes`` episodes x 101
points, 7 features, start difficulty U[0, 0.3]) for L learners (one key each).
Timed after a warm-up compile with ``block_until_ready``, best of ``repeats``:

* vbl cells: ``build_cell_map`` (Figure 5's default ``CellMapParams``), vmapped over L;
* NumPy: the same cell construction vectorised with ``np.add.at`` (float64), looped over
  learners - the baseline; its labels are checked against vbl's.

    python benchmarks/state_map_build.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vbl  # noqa: E402,F401
from benchmarks.hardware import hardware_info  # noqa: E402
from vbl.envs.shooting import ShootingEnv, ShootingParams  # noqa: E402
from vbl.spaces.action_based import (  # noqa: E402
    ExperienceParams,
    FeatureParams,
    collect_experience,
    sec2_features,
)
from vbl.spaces.action_cells import CellMapParams, build_cell_map  # noqa: E402


def collect(learners: int, episodes: int):
    env, fp = ShootingEnv(), FeatureParams()
    cp = ExperienceParams(episodes_per_action=episodes, difficulty_hi=0.3)
    fn = jax.jit(jax.vmap(lambda k: collect_experience(
        env, ShootingParams(), k, lambda o: sec2_features(o, fp), env.num_actions, cp)))
    return jax.block_until_ready(fn(jax.random.split(jax.random.PRNGKey(0), learners)))


def best_time(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))                       # compile
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def numpy_cells(x, valid, goal, edges, p: CellMapParams) -> np.ndarray:
    """Vectorised NumPy cell construction (float64) with vbl's edges; cell labels (C,)."""
    n_act, n_ep, t1, _ = x.shape
    w, n_pat = p.start_window, p.num_patterns
    idx = np.zeros(x.shape[:-1], np.int64)
    for d, b in enumerate(p.bins):
        idx = idx * b + np.minimum((x[..., d, None] > edges[d]).sum(-1), b - 1)
    digits = np.clip(np.round(x[..., -p.categorical_dims:] * (p.categorical_levels - 1)), 0,
                     p.categorical_levels - 1)
    pat = (digits * p.categorical_levels ** np.arange(p.categorical_dims)).sum(-1)
    cell = idx * n_pat + pat.astype(np.int64)
    n_cells = p.num_cells
    lab = np.full(n_cells, -1)
    ctime = np.zeros(n_cells)
    for it in range(p.max_iterations):
        hit_next = (lab[cell] >= 0) & valid
        reach = np.zeros((n_act, n_ep), bool)
        tm = np.zeros((n_act, n_ep))
        r_all = np.zeros((n_act, n_ep, t1 - 1), bool)
        t_all = np.zeros((n_act, n_ep, t1 - 1))
        for t in range(t1 - 2, -1, -1):
            g, h = goal[:, :, t], hit_next[:, :, t + 1]
            tm = 1.0 + np.where(g, 0.0, np.where(h, ctime[cell[:, :, t + 1]], tm))
            reach = g | h | reach
            r_all[:, :, t], t_all[:, :, t] = reach, tm
        c0 = cell[:, :, :w]
        start = valid[:, :, :w] & (lab[c0] < 0)
        ok_pt = start & r_all[:, :, :w]
        n_in, n_ok, s_tm = (np.zeros((n_act, n_cells)) for _ in range(3))
        for a in range(n_act):
            np.add.at(n_in[a], c0[a][start[a]], 1.0)
            np.add.at(n_ok[a], c0[a][ok_pt[a]], 1.0)
            np.add.at(s_tm[a], c0[a][ok_pt[a]], t_all[a, :, :w][ok_pt[a]])
        rel = n_ok / np.maximum(n_in, 1.0)
        e_tm = s_tm / np.maximum(n_ok, 1.0)
        ok = (n_in >= p.min_points) & (rel >= p.min_reliability) & (lab < 0)[None]
        value = np.where(ok, rel * p.discount ** e_tm, -1.0)
        best = value.argmax(0)
        new = ok.any(0)
        if not new.any():
            break
        lab = np.where(new, it * n_act + best, lab)
        ctime = np.where(new, e_tm[best, np.arange(n_cells)], ctime)
    return lab


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="300 episodes per primitive, L <= 2")
    args = ap.parse_args()
    episodes = 300 if args.quick else 1000
    sizes = [1, 2] if args.quick else [1, 4]
    cp = CellMapParams()
    cells = jax.jit(jax.vmap(lambda e: build_cell_map(e, cp)))
    exp_all = collect(max(sizes), episodes)
    rows = []
    for n in sizes:
        exp = jax.tree_util.tree_map(lambda a: a[:n], exp_all)  # noqa: B023
        t_cells = best_time(cells, exp, repeats=3)
        cm = cells(exp)
        x, valid, goal = (np.asarray(a, np.float64 if a.dtype == jnp.float32 else None)
                          for a in (exp.x, exp.valid, exp.goal))
        t0 = time.perf_counter()
        labs = [numpy_cells(x[i], valid[i].astype(bool), goal[i].astype(bool),
                            np.asarray(cm.edges[i], np.float64), cp) for i in range(n)]
        t_np = time.perf_counter() - t0
        same = all(np.array_equal(labs[i], np.asarray(cm.cell_state[i])) for i in range(n))
        rows.append(dict(learners=n, cells_s=t_cells, numpy_cells_s=t_np,
                         x_vs_numpy=t_np / t_cells, numpy_labels_equal=same))
        print(rows[-1], flush=True)
    out = dict(benchmark="state_map_build", quick=args.quick, hardware=hardware_info(),
               setting=dict(episodes_per_action=episodes, primitives=9, points_per_episode=101,
                            features=7, cells=cp.num_cells, bins=list(cp.bins)), rows=rows)
    res = ROOT / "benchmarks" / "results"
    res.mkdir(parents=True, exist_ok=True)
    (res / "state_map_build.json").write_text(json.dumps(out, indent=2))
    md = markdown(out)
    (res / "state_map_build.md").write_text(md)
    print(md)


def markdown(out: dict) -> str:
    """The results table of one run (``out``: the JSON the run writes)."""
    hw, st = out["hardware"], out["setting"]
    md = [f"Figure 5 map construction ({st['episodes_per_action']} episodes x "
          f"{st['primitives']} primitives x {st['points_per_episode']} points per learner, "
          f"{st['cells']} cells) on {hw['cpu']} ({hw['cores']} cores, shared, load "
          f"{hw['load_average']:.1f}), jax {hw['jax']}; best of 3 after compilation.", "",
          "| learners | cells (s) | NumPy cells (s) | x NumPy | NumPy labels equal |",
          "|---|---|---|---|---|"]
    for r in out["rows"]:
        md.append(f"| {r['learners']} | {r['cells_s']:.3f} | {r['numpy_cells_s']:.2f} | "
                  f"{r['x_vs_numpy']:.1f} | {r['numpy_labels_equal']} |")
    return "\n".join(md) + "\n"


if __name__ == "__main__":
    main()
