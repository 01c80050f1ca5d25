"""Figure 5: off-line, action-based state-space construction (paper Section 2.1).

Each learner collects experience in parallel shooting environments (each episode holds
one primitive) and grows its state map backwards from the goal
(:mod:`vbl.spaces.action_cells`: states made of quantile cells), then refines the map's
policy in closed loop (:mod:`vbl.spaces.cell_refine`). It is compared
with the grid baseline exactly as the ``grid_shooting`` experiment trains and evaluates it
(its default config, used by reference through :func:`grid_shooting`: Q-learning on the
programmer's 319-state grid with macro actions and Learning from Easy Missions), trained
in the chunks of this run. ``final``
evaluates the map's policy on fresh starts at the grid's task difficulty
(``grid.train.eval_difficulty``) and takes the grid's own final evaluation (greedy and
random policy) at the same difficulty. The report draws Figure 5 (the map on (ball size,
goal size) with ball and goal centred and the goal frontal, labels = action + transitions
to the goal, darker = earlier division, the grid lines over it).

Run: ``vbl run fig5_action_based --quick`` or ``python experiments/fig5_action_based.py``.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.programs import QTrainParams
from vbl.agents.qlearning import QRunnerParams
from vbl.engine import Experiment, Program, ReportSection, register
from vbl.engine.experiment import PaperRow
from vbl.engine.registry import load_script
from vbl.engine.report import seeds_cell
from vbl.envs.shooting import ShootingEnv, ShootingParams
from vbl.params import ParamError, param, section, validate
from vbl.spaces.action_based import (
    CollectParams,
    FeatureParams,
    collect_experience,
    rollout_success,
    sec2_features,
)
from vbl.spaces.action_cells import (
    CellMap,
    CellMapParams,
    build_cell_map,
    cell_index,
    cell_policy_action,
    check_cells,
    classify_cells,
    num_cell_states,
)
from vbl.spaces.cell_refine import (
    RefinedMap,
    RefineParams,
    initial_units,
    num_refined_states,
    num_refined_units,
    refine_cell_map,
    refined_policy_action,
)
from vbl.spaces.grid import NUM_GRID_STATES, GridParams

F32 = jnp.float32
ENV = ShootingEnv()


def grid_shooting() -> ModuleType:
    """``experiments/grid_shooting.py`` (the grid baseline experiment) as the registry loads
    it, so that its settings are used by reference: whatever that experiment trains is what
    Figures 5 and 9 compare with."""
    return load_script(Path(__file__).with_name("grid_shooting.py"))


def _gs_default(name: str):
    return lambda: getattr(grid_shooting().EXPERIMENT.default_config, name)


EVAL_DIFFICULTY = 0.1
"""Start difficulty of Figure 5's comparisons (map, grid, random policy): grid_shooting's own
task is fully random starts (1.0), where neither learner shoots within this env's time
limit; 0.1 is what the Figure 5 numbers in the README were measured at."""


def _train_default():
    return _gs_default("train")().replace(eval_difficulty=EVAL_DIFFICULTY)


@struct.dataclass
class GridBaseline:
    """The grid baseline exactly as ``grid_shooting`` trains and evaluates it (its default
    config: Q-learning on the 319-state grid, macro actions, Learning from Easy Missions up
    to its task difficulty), on this experiment's ``env``."""

    grid: GridParams = section(_gs_default("grid"), doc="grid boundaries (grid_shooting's)")
    agent: QRunnerParams = section(_gs_default("agent"), doc="Q-learning, macro actions, LEM "
                                   "(grid_shooting's)")
    train: QTrainParams = section(_train_default, doc="run length and evaluation "
                                  "(grid_shooting's, evaluation pinned to start difficulty "
                                  "0.1); train.eval_difficulty is the start difficulty of every "
                                  "comparison")


def grid_config(env: ShootingParams, g: GridBaseline):
    """``grid_shooting``'s config with these sections (traced or static)."""
    gs = grid_shooting()
    return gs.EXPERIMENT.default_config.replace(env=env, grid=g.grid, agent=g.agent,
                                                train=g.train)


def grid_program(env: ShootingParams, g: GridBaseline) -> Program:
    """``grid_shooting``'s engine program for these settings (static fields of ``g``)."""
    return grid_shooting().EXPERIMENT.make_program(grid_config(env, g))


@struct.dataclass
class EvalParams:
    episodes: int = param(256, doc="evaluation episodes (fresh starts) of the map's policy, at "
                          "grid.train.eval_difficulty", static=True, ge=1)
    grid_baseline: bool = param(True, doc="train and evaluate the grid baseline in this run "
                                "(off: one empty chunk, the map only; --quick, to keep its "
                                "compile time short)", static=True)


def _collect_default() -> CollectParams:
    """Start difficulty U[0, 0.3] (0 = ball in front near the goal): the data lie where the
    map is evaluated (0.1) and F reaches the goal from far more of them than from fully
    random starts (chosen on single-seed prototypes, not re-measured through the engine:
    docs/findings/fig5_action_based.md, "Deviations and the evidence for them")."""
    return CollectParams(difficulty_hi=0.3)


@struct.dataclass
class Fig5Config:
    env: ShootingParams = section(ShootingParams, doc="shooting task")
    features: FeatureParams = section(FeatureParams, doc="feature normalisation")
    collect: CollectParams = section(_collect_default, doc="experience collection")
    cells: CellMapParams = section(CellMapParams, doc="cell construction")
    refine: RefineParams = section(RefineParams, doc="closed-loop refinement of the cell map "
                                   "(an extension of the paper: refine.iterations=0 turns it "
                                   "off)")
    grid: GridBaseline = section(GridBaseline, doc="grid baseline (grid_shooting's settings; "
                                 "its chunks are this run's chunks)")
    eval: EvalParams = section(EvalParams, doc="evaluation of the map")


def ball_speed(state) -> jax.Array:
    """The ball's speed (m/s) in a shooting state, recorded with the experience."""
    return jnp.linalg.norm(state.world.ball_vel).astype(F32)


@struct.dataclass
class Carry:
    smap: CellMap
    grid: object
    refined: RefinedMap | None
    collect_primitives: jax.Array   # () float32 primitives of the collection
    grid_primitives: jax.Array      # () float32 primitives of the grid's finished episodes


def make_program(cfg: Fig5Config) -> Program:
    n_act = ENV.num_actions
    cat = cfg.cells.categorical_dims
    if cat > (2 if cfg.features.lost_sides else 0):
        raise ParamError(f"cells.categorical_dims={cat}: only the lost-side features are "
                         "categorical (2 with features.lost_sides, else 0)")
    check_cells(cfg.cells, cfg.features.dim, cfg.collect.horizon)
    act_fn, count_fn = cell_policy_action, num_cell_states
    gprog = grid_program(cfg.env, cfg.grid) if cfg.eval.grid_baseline else None
    refine = cfg.refine.iterations > 0
    validate(cfg.refine, "refine.")

    def init(key, c):
        k_col, k_build, k_grid = jax.random.split(key, 3)
        k_ref = jax.random.fold_in(k_build, 1)    # keeps the keys of the recorded runs
        feat = lambda o: sec2_features(o, c.features)  # noqa: E731
        exp = collect_experience(ENV, c.env, k_col, feat, n_act, c.collect, ball_speed)
        smap = build_cell_map(exp, c.cells)
        refined = (refine_cell_map(ENV, c.env, k_ref, feat, smap, c.refine) if refine
                   else None)
        grid = None if gprog is None else gprog.init(k_grid, grid_config(c.env, c.grid))
        return Carry(smap=smap, grid=grid, refined=refined,
                     collect_primitives=jnp.sum(exp.valid[..., :-1]).astype(F32),
                     grid_primitives=jnp.zeros((), F32))

    def step(carry, c):
        if gprog is None:
            return carry, {"map_states": count_fn(carry.smap).astype(F32)}
        g, m = gprog.step(carry.grid, grid_config(c.env, c.grid))
        prims = carry.grid_primitives + m["episodes"] * m["mean_primitives"]
        curve = "eval_success" if "eval_success" in m else "train_success"  # grid.train.eval_curve
        return carry.replace(grid=g, grid_primitives=prims.astype(F32)), {
            "episodes": m["episodes"], f"grid_{curve}": m[curve],
            "grid_difficulty": m["difficulty"], "map_states": count_fn(carry.smap).astype(F32)}

    def final(carry, c, key):
        k_map, k_grid = jax.random.split(key)
        ep = c.env.replace(start_difficulty=jnp.asarray(c.grid.train.eval_difficulty, F32))
        feat = lambda o: sec2_features(o, c.features)  # noqa: E731
        sm = carry.smap
        ok, _ = rollout_success(ENV, ep, k_map, lambda o, _: act_fn(sm, feat(o)),
                                cfg.eval.episodes, cfg.env.max_steps)
        out = {"map_success": jnp.mean(ok.astype(F32)),
               "map_states": count_fn(sm).astype(F32),
               "map_iterations": sm.iterations.astype(F32),
               "action": sm.action.astype(F32), "transitions": sm.transitions.astype(F32),
               "order": sm.order.astype(F32), "active": sm.active.astype(F32),
               "collect_primitives": carry.collect_primitives}
        if refine:
            rm = carry.refined
            k_ref = jax.random.fold_in(k_map, 1)
            ok_r, _ = rollout_success(ENV, ep, k_ref,
                                      lambda o, _: refined_policy_action(sm, rm, feat(o)),
                                      cfg.eval.episodes, cfg.env.max_steps)
            out.update(refined_success=jnp.mean(ok_r.astype(F32)),
                       refined_states=num_refined_states(rm, n_act, cfg.refine.max_transitions
                                                         ).astype(F32),
                       refined_units=num_refined_units(rm).astype(F32),
                       refine_primitives=rm.primitives, refine_train_success=rm.train_success,
                       refined_policy=rm.policy.astype(F32),
                       refined_transitions=rm.transitions.astype(F32))
        out.update(edges=sm.edges, cell_state=sm.cell_state.astype(F32),
                   cell_time=sm.cell_time, cell_transitions=sm.cell_transitions.astype(F32),
                   fallback=sm.fallback.astype(F32))
        if gprog is not None:
            g = gprog.final(carry.grid, grid_config(c.env, c.grid), k_grid)
            out.update(grid_success=g["greedy_success"], random_success=g["random_success"],
                       grid_primitives=carry.grid_primitives)
        return out

    return Program(init=init, step=step, final=final,
                   num_chunks=1 if gprog is None else gprog.num_chunks)


def map_of(final: dict, seed: int, cfg: Fig5Config | None = None) -> CellMap:
    """The cell map of one learner from the run's ``final`` arrays (one sweep point)
    (``cfg``: the run's config, for the static settings; default: Figure 5's)."""
    c = (Fig5Config() if cfg is None else cfg).cells
    g = lambda k, t=np.float32: np.asarray(final[k])[seed].astype(t)  # noqa: E731
    return CellMap(edges=g("edges"), cell_state=g("cell_state", np.int32),
                   cell_time=g("cell_time"), cell_transitions=g("cell_transitions", np.int32),
                   fallback=g("fallback", np.int32), action=g("action", np.int32),
                   transitions=g("transitions", np.int32), order=g("order", np.int32),
                   active=g("active", bool), iterations=np.int32(0), bins=tuple(c.bins),
                   categorical_dims=c.categorical_dims, categorical_levels=c.categorical_levels)


def _slice(cfg: Fig5Config, n: int) -> np.ndarray:
    """Feature vectors (n, n, D) of Figure 5's slice: x1 ball size along the columns, x3
    goal size along the rows, x2 = x4 = 0 px, x5 = 0, both objects visible."""
    u = (np.arange(n) + 0.5) / n
    b, g = np.meshgrid(u, u)
    x = np.full((n, n, cfg.features.dim), 0.5, np.float32)
    x[..., 0], x[..., 2] = b, g
    return x


def _draw_slice(cfg: Fig5Config, region: np.ndarray, shade: np.ndarray, label, title: str,
                path: Path) -> Path:
    """Draw regions (n, n) int (< 0: none) of the slice, grey ``shade`` (n, n) in [0, 1],
    ``label(region) -> str`` at each region's centre, the grid's boundaries in blue."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fp, n = cfg.features, region.shape[0]
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.imshow(shade, origin="lower", extent=(0, fp.ball_size_max, 0, fp.goal_size_max),
              cmap="gray", vmin=0, vmax=1, aspect="auto")
    for r in np.unique(region[region >= 0]):
        rr, cc = np.nonzero(region == r)
        ax.text((cc.mean() + 0.5) / n * fp.ball_size_max, (rr.mean() + 0.5) / n
                * fp.goal_size_max, label(r), ha="center", va="center", fontsize=8,
                color="red")
    gp = cfg.grid.grid
    for v in (gp.ball_size_lower, gp.ball_size_upper):
        ax.axvline(v, color="C0", lw=1)
    for v in (gp.goal_size_lower, gp.goal_size_upper):
        ax.axhline(v, color="C0", lw=1)
    ax.set_xlabel("ball size x1 [px]")
    ax.set_ylabel("goal size x3 [px]")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_fig5(final: dict, cfg: Fig5Config, out: Path, seed: int = 0, n: int = 160) -> Path:
    """The map of one learner on Figure 5's slice (:func:`_slice`). Darker = earlier
    division; label = action + transitions to the goal."""
    from vbl.world.robots import action_labels
    sm = map_of(final, seed, cfg)
    s = np.asarray(classify_cells(sm, jnp.asarray(_slice(cfg, n))))
    order = np.where(s >= 0, np.asarray(sm.order)[np.maximum(s, 0)], -1)
    n_it = max(int(np.asarray(sm.order)[np.asarray(sm.active)].max(initial=0)) + 1, 1)
    shade = np.where(order >= 0, 0.15 + 0.7 * order / max(n_it, 1), 1.0)
    labels = action_labels("two_motor")
    return _draw_slice(
        cfg, s, shade, lambda st: f"{labels[int(sm.action[st])]}$_{{{int(sm.transitions[st])}}}$",
        f"Fig. 5 map (cells, seed {seed}): {int(np.asarray(sm.active).sum())} "
        "states; blue = grid", out / "fig5_state_map.png")


def plot_refined(final: dict, cfg: Fig5Config, out: Path, seed: int = 0, n: int = 160) -> Path:
    """The refined policy of one learner on Figure 5's slice: label = primitive +
    transitions to the goal, darker = fewer transitions; white = never reached the goal in
    the refinement."""
    from vbl.world.robots import action_labels
    cm = map_of(final, seed, cfg)
    unit_of, _ = initial_units(cm, cfg.refine.units)
    pol = np.asarray(final["refined_policy"])[seed].astype(int)
    trans = np.asarray(final["refined_transitions"])[seed].astype(int)
    unit = np.asarray(unit_of)[np.asarray(cell_index(cm, jnp.asarray(_slice(cfg, n))))]
    t = trans[unit]
    shade = np.where(t > 0, 0.15 + 0.7 * (t - 1) / max(int(trans.max(initial=1)), 1), 1.0)
    labels = action_labels("two_motor")
    return _draw_slice(
        cfg, np.where(t > 0, unit, -1), shade,
        lambda un: f"{labels[pol[un]]}$_{{{trans[un]}}}$",
        f"refined map (seed {seed}): {int(final['refined_states'][seed])} states; "
        "blue = grid", out / "fig5_refined_map.png")


def ci95(v) -> tuple[float, float]:
    """Mean and half-width of the 95% t interval over seeds (0 for one seed)."""
    from vbl.engine.results import t_quantile_975

    v = np.asarray(v, float)
    h = t_quantile_975(len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else 0.0
    return float(v.mean()), float(h)


def report(res) -> ReportSection:
    cfg = res.config
    fin = {k: np.asarray(v)[0] for k, v in res.final.items()}
    figs = (plot_fig5(fin, cfg, Path(res.out_dir)),)
    if "refined_policy" in fin:
        figs += (plot_refined(fin, cfg, Path(res.out_dir)),)

    def ms(k, f="{:.3f}"):
        m, h = ci95(fin[k])
        return f"{f.format(m)} ± {f.format(h)}"

    seeds = len(fin["map_success"])
    gt = cfg.grid.train
    st = ci95(fin["map_states"])
    md = [f"Greedy policies on fresh starts at start difficulty {gt.eval_difficulty} (the grid "
          f"baseline's task difficulty; 1 = fully random), {seeds} seeds, mean ± 95% CI; the "
          f"map's policy on {cfg.eval.episodes} starts per seed.", "",
          "| method | states | success rate |", "|---|---|---|",
          f"| action-based map | {ms('map_states', '{:.1f}')} | {ms('map_success')} |"]
    refined = "refined_success" in fin
    if refined:
        md += [f"| same map, closed-loop refinement (vbl extension) | "
               f"{ms('refined_states', '{:.1f}')} (policy table: "
               f"{ms('refined_units', '{:.0f}')} units) | {ms('refined_success')} |"]
    if "grid_success" in fin:
        map_m, grid_m = ci95(fin["map_success"]), ci95(fin["grid_success"])
        overlap = abs(map_m[0] - grid_m[0]) <= map_m[1] + grid_m[1]
        md += [f"| grid baseline (Q-learning, grid_shooting) | {NUM_GRID_STATES} | "
               f"{ms('grid_success')} |",
               f"| random policy (grid's macro actions) | | {ms('random_success')} |", "",
               f"The grid baseline is grid_shooting's default config (with LEM), trained for "
               f"{gt.num_chunks} chunks and evaluated by its own final evaluation "
               f"({gt.final_eval_rounds} x {gt.eval_envs} starts per seed).", "",
               "What must hold: success at least the grid baseline's with fewer states than "
               f"{NUM_GRID_STATES}: success {'yes' if map_m[0] >= grid_m[0] else '**no**'} "
               f"({map_m[0]:.3f} vs {grid_m[0]:.3f}{', intervals overlap' if overlap else ''}"
               f"); states {'yes' if st[0] < NUM_GRID_STATES else '**no**'} ({st[0]:.1f})."]
        if refined:
            r_m, r_st = ci95(fin["refined_success"]), ci95(fin["refined_units"])
            md += ["", f"With the closed-loop refinement: success "
                   f"{'yes' if r_m[0] >= grid_m[0] else '**no**'} ({r_m[0]:.3f} vs "
                   f"{grid_m[0]:.3f}); policy-table rows "
                   f"{'yes' if r_st[0] < NUM_GRID_STATES else '**no**'} ({r_st[0]:.0f} vs "
                   f"{NUM_GRID_STATES})."]
        md += ["", "Experience (primitives per seed, mean): collection "
               f"{fin['collect_primitives'].mean():,.0f}"
               + (f" + refinement {fin['refine_primitives'].mean():,.0f}" if refined else "")
               + f"; grid baseline (finished training episodes) "
               f"{fin['grid_primitives'].mean():,.0f}."]
    else:
        md += ["", "Grid baseline not run (eval.grid_baseline off, e.g. --quick): see "
               "grid_shooting and the full run of this experiment."]
    md += ["", f"Construction: cells; the map took "
           f"{ms('map_iterations', '{:.1f}')} construction iterations."]
    if refined:
        r = cfg.refine
        md += ["", f"Refinement (vbl.spaces.cell_refine): {r.iterations} iterations x "
               f"{r.episodes} on-policy episodes (epsilon {r.epsilon}, start difficulty "
               f"U[{r.difficulty_lo}, {r.difficulty_hi}]) re-choose each unit's primitive by "
               "its mean closed-loop score; the construction's partition is kept. States = "
               "(transitions to the goal, primitive) pairs of the refined policy."]
    return ReportSection(markdown="\n".join(md), figures=figs)


def paper_rows(res) -> list[PaperRow]:
    fin = {k: np.asarray(v)[0] for k, v in res.final.items()}
    claim = "fewer states than the 319-state grid (no success rate)"
    rows = [PaperRow("Figure 5, action-based map (the construction): success / states", claim,
                     f"{seeds_cell(fin['map_success'], fmt='.3f')} / "
                     f"{seeds_cell(fin['map_states'], fmt='.1f')}")]
    if "refined_success" in fin:
        rows.append(PaperRow("Figure 5, same map with vbl's closed-loop refinement: success / "
                             "states", claim, f"{seeds_cell(fin['refined_success'], fmt='.3f')}"
                             f" / {seeds_cell(fin['refined_states'], fmt='.1f')}"))
    if "grid_success" in fin:
        rows.append(PaperRow("Figure 5, grid baseline (319 states) on the same starts: success",
                             "-", seeds_cell(fin["grid_success"], fmt=".3f")))
    return rows


EXPERIMENT = register(Experiment(
    name="fig5_action_based",
    description="Fig 5: off-line action-based state map vs the 319-state grid baseline",
    default_config=Fig5Config(),
    make_program=make_program,
    # --quick: a smaller collection and map, no grid baseline (its compile would double the
    # quick run's time; `vbl reproduce --quick` runs grid_shooting --quick anyway)
    quick={"collect.episodes_per_action": 300, "collect.horizon": 60, "cells.start_window": 30,
           "eval.episodes": 64, "eval.grid_baseline": False,
           "refine.iterations": 8, "refine.episodes": 128, "refine.horizon": 100},
    seeds=4,
    quick_seeds=2,
    paper_result=True,
    cost=119.0,  # s of a cold --quick run on 2 shared cores (compile-dominated; load ~2-3)
    paper={"figure": "5", "claim": "states differ from the programmer's grid; F/B labels"},
    report=report,
    renamed_metrics={"success_rate": "grid_eval_success"},
    paper_rows=paper_rows,
    # parameters added after run folders were written: the values of the code before them
    # (no refinement, the grid's curve after every chunk)
    legacy_values={"refine.iterations": 0, "grid.train.eval_every": 1,
                   "grid.agent.agent.update": "q_learning", "grid.agent.agent.mc_log": 128},
))

if __name__ == "__main__":
    from vbl.engine import main_for

    main_for(EXPERIMENT)
