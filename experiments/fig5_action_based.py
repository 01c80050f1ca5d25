"""Figure 5: off-line, action-based state-space construction (paper Section 2.1).

Each learner collects experience in parallel shooting environments (each episode holds
one primitive), grows its state map backwards from the goal
(:mod:`vbl.spaces.action_based`), and is compared with the grid baseline: tabular
Q-learning on the programmer's 319-state grid (:mod:`vbl.spaces.grid`, macro actions,
Learning from Easy Missions; :mod:`vbl.agents.qlearning`), trained in the chunks of the
run. ``final`` evaluates both greedy policies on fresh starts at ``eval.difficulty``.
The report draws Figure 5 (the map on (ball size, goal size) with ball and goal centred
and the goal frontal, labels = action + transitions to the goal, darker = earlier
division, the grid lines over it).

Run: ``vbl run fig5_action_based --quick`` or ``python experiments/fig5_action_based.py``.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.qlearning import QRunnerParams, make_qlearning_runner
from vbl.engine import Experiment, Program, ReportSection, register
from vbl.envs.shooting import ShootingEnv, ShootingParams
from vbl.params import param, section
from vbl.spaces.action_based import (
    ActionBasedParams,
    CollectParams,
    FeatureParams,
    StateMap,
    build_state_map,
    classify,
    collect_experience,
    num_states,
    policy_action,
    rollout_success,
    sec2_features,
)
from vbl.spaces.grid import GridParams, grid_state

F32 = jnp.float32
ENV = ShootingEnv()


@struct.dataclass
class EvalParams:
    difficulty: float = param(0.1, doc="start difficulty of the evaluation episodes (both "
                              "methods)", ge=0.0, le=1.0)
    episodes: int = param(256, doc="evaluation episodes (fresh starts) of each policy",
                          static=True, ge=1)
    grid_steps: int = param(1500, doc="greedy grid-baseline evaluation: learner steps (macro "
                            "actions) for each of its envs' first episode", static=True, ge=1)


@struct.dataclass
class Fig5Train:
    num_chunks: int = param(40, doc="chunks = grid-baseline training chunks (the map is built "
                            "at init)", static=True, ge=1)


def _grid_agent() -> QRunnerParams:
    """The grid baseline exactly as ``experiments/grid_shooting.py`` trains it (its
    ``_agent()``): discount 0.98 per primitive, LEM judging convergence by the mean |dQ| over
    100 learner steps (threshold 4e-3, difficulty steps 0.05), 64 envs x 100 steps a chunk."""
    a = QRunnerParams()
    agent = a.agent.replace(discount=0.98)
    lem = a.lem.replace(statistic="mean", window=100, threshold=4e-3, step=0.05)
    return a.replace(agent=agent, lem=lem, num_envs=64, chunk_steps=100)


@struct.dataclass
class Fig5Config:
    env: ShootingParams = section(ShootingParams, doc="shooting task")
    features: FeatureParams = section(FeatureParams, doc="feature normalisation")
    collect: CollectParams = section(CollectParams, doc="experience collection")
    build: ActionBasedParams = section(ActionBasedParams, doc="construction thresholds")
    grid: QRunnerParams = section(_grid_agent, doc="grid baseline (Q-learning on 319 states, "
                                  "grid_shooting's settings)")
    grid_bounds: GridParams = section(GridParams, doc="grid category boundaries")
    eval: EvalParams = section(EvalParams, doc="evaluation")
    train: Fig5Train = section(Fig5Train, doc="run length")


@struct.dataclass
class Carry:
    smap: StateMap
    grid: object


def make_program(cfg: Fig5Config) -> Program:
    n_act = ENV.num_actions
    runner = make_qlearning_runner(ENV, lambda o: grid_state(o, cfg.grid_bounds), cfg.grid,
                                   cfg.env)
    # the grid's greedy evaluation on as many fresh starts as the map's (one env each)
    ev_runner = make_qlearning_runner(ENV, lambda o: grid_state(o, cfg.grid_bounds),
                                      cfg.grid.replace(num_envs=cfg.eval.episodes), cfg.env)

    def init(key, c):
        k_col, k_build, k_grid = jax.random.split(key, 3)
        feat = lambda o: sec2_features(o, c.features)  # noqa: E731
        exp = collect_experience(ENV, c.env, k_col, feat, n_act, c.collect)
        smap = build_state_map(exp, c.build, k_build)
        return Carry(smap=smap, grid=runner.init(k_grid, c.grid, c.env))

    def step(carry, c):
        g, m = runner.run_chunk(carry.grid, c.grid, c.env)
        eps = jnp.sum(m["episodes"]).astype(F32)
        return carry.replace(grid=g), {
            "episodes": eps,
            "success_rate": jnp.sum(m["successes"]).astype(F32) / jnp.maximum(eps, 1.0),
            "grid_difficulty": m["difficulty"][-1].astype(F32),
            "map_states": num_states(carry.smap).astype(F32)}

    def final(carry, c, key):
        k_map, k_grid = jax.random.split(key)
        ep = c.env.replace(start_difficulty=c.eval.difficulty)
        feat = lambda o: sec2_features(o, c.features)  # noqa: E731
        sm = carry.smap
        ok, n = rollout_success(ENV, ep, k_map, lambda o, _: policy_action(sm, feat(o)),
                                cfg.eval.episodes, cfg.env.max_steps)
        g = ev_runner.evaluate(k_grid, carry.grid.q, c.grid.replace(num_envs=cfg.eval.episodes),
                               ep, cfg.eval.grid_steps)
        return {"map_success": jnp.mean(ok.astype(F32)),
                "grid_success": g["success_rate"].astype(F32),
                "map_states": num_states(sm).astype(F32),
                "map_iterations": sm.iterations.astype(F32),
                "grid_states": jnp.float32(319.0),
                "centre": sm.centre, "shape": sm.shape,
                "ell_active": sm.ell_active.astype(F32), "ell_state": sm.ell_state.astype(F32),
                "action": sm.action.astype(F32), "transitions": sm.transitions.astype(F32),
                "order": sm.order.astype(F32), "active": sm.active.astype(F32)}

    return Program(init=init, step=step, num_chunks=cfg.train.num_chunks, final=final)


def map_of(final: dict, seed: int) -> StateMap:
    """The StateMap of one learner from the run's ``final`` arrays (one sweep point)."""
    g = lambda k, t=np.float32: np.asarray(final[k])[seed].astype(t)  # noqa: E731
    return StateMap(centre=g("centre"), shape=g("shape"), ell_active=g("ell_active", bool),
                    ell_state=g("ell_state", np.int32), action=g("action", np.int32),
                    transitions=g("transitions", np.int32), order=g("order", np.int32),
                    active=g("active", bool), iterations=np.int32(0))


def plot_fig5(final: dict, cfg: Fig5Config, out: Path, seed: int = 0, n: int = 160) -> Path:
    """The map of one learner on (ball size x1, goal size x3); x2 = x4 = 0 px, x5 = 0, both
    objects visible. Darker = earlier division; label = action + transitions to the goal."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vbl.world.robots import action_labels
    sm = map_of(final, seed)
    fp = cfg.features
    u = (np.arange(n) + 0.5) / n
    b, g = np.meshgrid(u, u)                                  # x1 (cols), x3 (rows)
    x = np.full((n, n, fp.dim), 0.5, np.float32)
    x[..., 0], x[..., 2] = b, g
    s = np.asarray(classify(sm, jnp.asarray(x)))
    order = np.where(s >= 0, np.asarray(sm.order)[np.maximum(s, 0)], -1)
    n_it = max(int(np.asarray(sm.order)[np.asarray(sm.active)].max(initial=0)) + 1, 1)
    shade = np.where(order >= 0, 0.15 + 0.7 * order / max(n_it, 1), 1.0)
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ext = (0, fp.ball_size_max, 0, fp.goal_size_max)
    ax.imshow(shade, origin="lower", extent=ext, cmap="gray", vmin=0, vmax=1, aspect="auto")
    labels = action_labels("two_motor")
    for st in np.unique(s[s >= 0]):
        rr, cc = np.nonzero(s == st)
        a, t = int(sm.action[st]), int(sm.transitions[st])
        ax.text((cc.mean() + 0.5) / n * fp.ball_size_max, (rr.mean() + 0.5) / n
                * fp.goal_size_max, f"{labels[a]}$_{{{t}}}$", ha="center", va="center",
                fontsize=8, color="red")
    gp = cfg.grid_bounds
    for v in (gp.ball_size_lower, gp.ball_size_upper):
        ax.axvline(v, color="C0", lw=1)
    for v in (gp.goal_size_lower, gp.goal_size_upper):
        ax.axhline(v, color="C0", lw=1)
    ax.set_xlabel("ball size x1 [px]")
    ax.set_ylabel("goal size x3 [px]")
    ax.set_title(f"Figure 5: action-based map (seed {seed}), "
                 f"{int(np.asarray(sm.active).sum())} states; blue: grid")
    fig.tight_layout()
    path = out / "fig5_state_map.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def report(res) -> ReportSection:
    cfg = res.config
    fin = {k: np.asarray(v)[0] for k, v in res.final.items()}
    fig = plot_fig5(fin, cfg, Path(res.out_dir))

    def ms(k):
        v = fin[k]
        return f"{v.mean():.3f} +- {v.std(ddof=1) if len(v) > 1 else 0.0:.3f}"

    md = ["| method | states | success rate (fresh starts, difficulty "
          f"{cfg.eval.difficulty}) |", "|---|---|---|",
          f"| action-based map | {ms('map_states')} | {ms('map_success')} |",
          f"| grid baseline (Q-learning) | 319 | {ms('grid_success')} |", "",
          f"Mean +- std over {len(fin['map_success'])} seeds; the map took "
          f"{ms('map_iterations')} iterations."]
    return ReportSection(markdown="\n".join(md), figures=(fig,))


EXPERIMENT = register(Experiment(
    name="fig5_action_based",
    description="Fig 5: off-line action-based state map vs the 319-state grid baseline",
    default_config=Fig5Config(),
    make_program=make_program,
    quick={"collect.episodes_per_action": 300, "collect.horizon": 60, "build.start_window": 30,
           "build.max_iterations": 6, "train.num_chunks": 3, "eval.episodes": 64,
           "grid.num_envs": 16, "eval.grid_steps": 400},
    seeds=4,
    quick_seeds=2,
    paper_result=True,
    paper={"figure": "5", "claim": "states differ from the programmer's grid; F/B labels"},
    report=report,
))

if __name__ == "__main__":
    from vbl.engine import main_for

    main_for(EXPERIMENT)
