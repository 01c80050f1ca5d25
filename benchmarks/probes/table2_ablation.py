"""Probe: where Table 2's CVA state loses to the velocity oracle (an ablation at quick scale).

What it measures: ``table2_shoot_pass --quick`` (16 seeds, shooting and passing) with the
CVA state built in other ways, with one-step Q-learning and with Monte Carlo values (the
``monte_carlo`` preset): greedy success of the CVA state and of the CVA state identified
from the features plus the ball's true velocity, beside the velocity oracle (current
features + true velocity) and the current features, and the training episodes' primitives
per decision. A gap between "CVA + true velocity" and the oracle is lost in how the state
is built and quantised, not in estimating the velocity.

Variants (the current-feature rows do not depend on them and come from ``figure11``):

* ``figure11``: a CVA state of every observed object (the paper's Figure 11): the ball's 8
  components, the goal's and the other robot's 4 (``FIGURE11``); every row;
* ``index_ends_actions``: ``figure11`` where a macro action ends when the state's index
  changes, command terms included (the rule before the perceived index; a state map of
  this probe);
* ``no_command_terms`` and ``cancor_weights``: rows of the results file measured on the
  tag ``prune/cva-ablation-knobs``, whose ``cva.command_terms=False`` (``figure11``
  without the command terms) and ``cva.code_weights=cancor`` (components weighted by
  their canonical correlations in the quantiser) measured no gain and were removed;
* ``aic_order``: ``figure11`` with ``cva.keep_beyond_order=False`` (the components beyond
  the AIC order are 0: the paper's state);
* ``ball_4``: ``figure11`` with ``cva.n_used_objects=(4, 4, 4)``;
* ``cva_ball_other``: the CVA states of the ball and the other robot, the goal's current
  features (``cva.objects=(ball, other)``, ``cva.extra=(goal,)``);
* ``defaults``: Table 2's state, the ball's CVA state with the goal's and the other
  robot's current features;
* ``whiten``: ``defaults`` with each block of the state vector whitened (its covariance
  over the collected states made the identity: rotated onto its principal axes and scaled
  by their standard deviations) instead of z-scored per component before its codebook is
  fitted (a state map of this probe);
* ``ball_codes_per_dim``: ``defaults`` with 256 ball codes for the CVA state's 8 ball
  components, 2 codes per dimension as the oracle's 64 codes over its 6 ball features
  (``cva.quantizer.group_codes=(256, 8, 8)``; the reference rows keep 64 codes: equal
  codes per dimension instead of equal codes per object).

Not an experiment and not a benchmark; run from the repository root:

    python benchmarks/probes/table2_ablation.py [--out runs/table2_ablation]
        [--variants NAME ...] [--updates q_learning monte_carlo] [--tiny]

Writes ``benchmarks/results/table2_ablation.json``, keeping the rows of earlier
invocations that this one does not rerun (``--tiny``: a smoke test at toy size that writes
into ``--out`` only). Cost: about 4-7 min per run on 2 cores (a process each). Cited by
docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULT = ROOT / "benchmarks" / "results" / "table2_ablation.json"

FIGURE11 = {"cva.objects": ("ball", "goal", "other"), "cva.n_used_objects": (8, 4, 4),
            "cva.extra": ()}
"""The construction the ablation starts from: a CVA state of every observed object (the
paper's Figure 11), the ball's 8 components and the others' 4."""

BASE = "figure11"  #: the variant run with every row (its current-feature and oracle rows)

VARIANTS = {
    "figure11": FIGURE11,
    "index_ends_actions": FIGURE11,
    "aic_order": {**FIGURE11, "cva.keep_beyond_order": False},
    "ball_4": {**FIGURE11, "cva.n_used_objects": (4, 4, 4)},
    "cva_ball_other": {"cva.objects": ("ball", "other"), "cva.n_used_objects": (8, 4),
                       "cva.extra": ("goal",)},
    "defaults": {},
    "whiten": {},
    "ball_codes_per_dim": {"cva.quantizer.group_codes": (256, 8, 8)},
}
MIN_VARIANCE = 1e-6
"""Whitening: principal variances below this (e.g. the zero padding of the shorter state
vector) are raised to it, so their axes stay 0 instead of dividing by 0."""
UPDATES = ("q_learning", "monte_carlo")
TINY = {"agent.num_envs": 4, "agent.chunk_steps": 10, "env.max_steps": 10,
        "train.num_chunks": 2, "train.eval_rounds": 1, "cva.collect_steps": 600,
        "cva.quantizer.group_codes": (4, 2, 2), "cva.quantizer.kmeans_iters": 1}


def whitening(x, groups):
    """``(mean (d,), w (d, d))``: ``(x - mean) @ w`` has the identity covariance within each
    block of ``groups`` (sizes of consecutive components) over the rows of ``x`` (N, d)."""
    import jax.numpy as jnp

    mean = jnp.mean(x, axis=0)
    w, start = jnp.zeros((x.shape[1],) * 2, jnp.float32), 0
    for size in groups:
        xc = x[:, start:start + size] - mean[start:start + size]
        var, axes = jnp.linalg.eigh(xc.T @ xc / x.shape[0])
        block = axes / jnp.sqrt(jnp.maximum(var, MIN_VARIANCE))
        w = w.at[start:start + size, start:start + size].set(block)
        start += size
    return mean, w


def whitened_map(env, p):
    """Table 2's state map whose blocks are whitened before the product codebook."""
    import jax
    from flax import struct

    from vbl.agents.cva_state import collect, history_wrapper, identify_object
    from vbl.agents.state_maps import CVAMap
    from vbl.envs.wrappers import HistoryParams, QuantizeWrapper
    from vbl.spaces.quantize import Quantizer, fit_quantizer, quantize

    @struct.dataclass
    class Whitened:
        quantizer: Quantizer
        mean: jax.Array
        w: jax.Array

    class WhitenedCVAMap(CVAMap):
        def __init__(self, env, p):
            super().__init__(env, p)
            self.env = QuantizeWrapper(history_wrapper(env, p, self.m, world=True),
                                       lambda q, x: quantize(q.quantizer, (x - q.mean) @ q.w))

        def prepare(self, key, c):  # prepare_state, whitened before the codebook
            hist = history_wrapper(self.base, self.p, self.m)
            k_col, k_q = jax.random.split(key)
            data = collect(self.base, k_col, c.env, self.p.collect_steps)
            models = tuple(identify_object(data["u"], data["obs"][:, sl], c.cva.ident, k,
                                           c.cva.keep_beyond_order)
                           for sl, k in zip(hist.slices, self.p.n_used_per_object(),
                                            strict=True))
            use_cva = jax.numpy.asarray(c.cva.use_cva, bool)
            xs = hist.replay(data["obs"], data["u"], data["start"],
                             HistoryParams(c.env, models, use_cva))
            mean, w = whitening(xs, hist.block_dims())
            qz = fit_quantizer(k_q, (xs - mean) @ w, c.cva.quantizer, groups=hist.block_dims())
            return models, Whitened(qz, mean, w), use_cva

    return WhitenedCVAMap(env, p)


def experiment(variant: str):
    """Table 2's experiment, or it on a state map of this probe."""
    from vbl.agents.state_maps import CVAMap
    from vbl.engine.registry import load_script
    from vbl.programs.table2 import table2_env
    from vbl.programs.tabular import make_tabular_program

    exp = load_script(ROOT / "experiments" / "table2_shoot_pass.py").EXPERIMENT
    if variant not in ("index_ends_actions", "whiten"):
        return exp

    class IndexEndsActions(CVAMap):
        def perceived(self, obs, c):
            return obs["index"]

    make_map = IndexEndsActions if variant == "index_ends_actions" else whitened_map
    return dataclasses.replace(exp, name=f"table2_{variant}", make_program=lambda cfg:
                               make_tabular_program(make_map(
                                   table2_env(cfg.task, cfg.ball_velocity), cfg.cva), cfg))


def rows(res) -> dict[str, dict]:
    """Per row ("shoot, cva + true velocity", ...): greedy success per seed (%) and the
    training episodes' primitives per decision per seed."""
    from vbl.programs.table2 import state_label, task_label
    from vbl.programs.tabular import decision_primitives

    out = {}
    for i, pt in enumerate(res.points):
        name = f"{task_label(pt, res.config)}, {state_label(pt, res.config)}"
        out[name] = {"greedy": (100.0 * np.asarray(res.final["greedy_success"][i])).tolist(),
                     "primitives_per_decision": decision_primitives(res, i).tolist()}
    return out


def run(variant: str, update: str, out: Path, tiny: bool) -> dict[str, dict]:
    from vbl.engine.runner import run_experiment

    exp = experiment(variant)
    sets = dict(VARIANTS[variant], **(TINY if tiny else {}))
    # the variants change the CVA state only: their current-feature rows are the base's
    sweep = None if variant == BASE else {
        "env.task_pass": [False, True], "cva.use_cva": [True], "ball_velocity": [False, True]}
    if tiny:  # one compilation: the shooter's two state vectors, no velocity control
        sweep = {"env.task_pass": [False], "cva.use_cva": [False, True], "ball_velocity": [False]}
    res = run_experiment(exp, sets=sets, sweep=sweep, quick=True, seeds=2 if tiny else None,
                         out=out / f"{variant}-{update}", overwrite=True, quiet=True,
                         plots=False, preset=None if update == "q_learning" else update)
    return rows(res)


def gaps(results: dict) -> dict:
    """Greedy success points, CVA + true velocity minus the oracle and CVA minus current
    features, per variant, update and task (Welch 95 % interval)."""
    from vbl.stats import welch_ci95

    out = {}
    for update, by_variant in results.items():
        base = by_variant.get(BASE)
        if base is None:
            continue
        for variant, r in by_variant.items():
            for task in ("shoot", "pass"):
                pairs = {"cva + true velocity - oracle": (f"{task}, cva + true velocity",
                                                          f"{task}, current + true velocity"),
                         "cva - current": (f"{task}, cva", f"{task}, current")}
                for what, (a, b) in pairs.items():
                    if a in r and b in base:
                        d, h = welch_ci95(np.asarray(r[a]["greedy"]),
                                          np.asarray(base[b]["greedy"]))
                        out.setdefault(update, {}).setdefault(variant, {})[
                            f"{task}: {what}"] = [float(d), float(h)]
    return out


def _cell(values) -> str:
    from vbl.stats import mean_ci95

    m, h = mean_ci95(np.asarray(values, np.float64))
    return f"{m:.1f} ± {h:.1f}"


def table(data: dict) -> str:
    """The findings' table of a results file: per update rule and variant, the CVA state's
    greedy success and its gap to the oracle when identified with the true velocity, per
    task, and the CVA learner's primitives per decision; then the reference rows."""
    head = ("| update | variant | shoot: CVA % | shoot: CVA + true velocity − oracle | pass: "
            "CVA % | pass: CVA + true velocity − oracle | primitives per decision, CVA: "
            "shoot / pass |")
    lines = [head, "|---|---|---|---|---|---|---|"]
    res, diffs = data["results"], data["differences"]
    for update, by_variant in res.items():
        for variant, r in by_variant.items():
            d = diffs.get(update, {}).get(variant, {})
            gap = [("{:+.1f} ± {:.1f}".format(*d[f"{t}: cva + true velocity - oracle"])
                    if f"{t}: cva + true velocity - oracle" in d else "-")
                   for t in ("shoot", "pass")]
            per = " / ".join(f"{np.mean(r[f'{t}, cva']['primitives_per_decision']):.2f}"
                             for t in ("shoot", "pass"))
            lines.append(f"| {update} | {variant} | {_cell(r['shoot, cva']['greedy'])} | "
                         f"{gap[0]} | {_cell(r['pass, cva']['greedy'])} | {gap[1]} | {per} |")
    lines += ["", "| update | reference row (figure11) | shoot % | pass % | primitives per "
              "decision: shoot / pass |", "|---|---|---|---|---|"]
    for update, by_variant in res.items():
        r = by_variant.get(BASE, {})
        for state in ("current", "current + true velocity"):
            if f"shoot, {state}" in r:
                per = " / ".join(f"{np.mean(r[f'{t}, {state}']['primitives_per_decision']):.2f}"
                                 for t in ("shoot", "pass"))
                lines.append(f"| {update} | {state} | {_cell(r[f'shoot, {state}']['greedy'])} "
                             f"| {_cell(r[f'pass, {state}']['greedy'])} | {per} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/table2_ablation", help="folder of the run folders")
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS),
                    help="default: every variant (--tiny: index_ends_actions)")
    ap.add_argument("--updates", nargs="+", default=list(UPDATES), choices=list(UPDATES))
    ap.add_argument("--tiny", action="store_true", help="smoke-test size (2 seeds, 2 chunks)")
    ap.add_argument("--table", action="store_true", help="print the table of the committed "
                    "results file and stop (no runs)")
    args = ap.parse_args(argv)
    if args.table:
        print(table(json.loads(RESULT.read_text())))
        return 0
    if args.tiny:
        args.variants, args.updates = args.variants or ["index_ends_actions"], ["q_learning"]
    args.variants = args.variants or list(VARIANTS)
    out = Path(args.out)
    dest = out / "table2_ablation.json" if args.tiny else RESULT
    dest.parent.mkdir(parents=True, exist_ok=True)
    jobs = [(u, v) for u in args.updates for v in args.variants]
    if len(jobs) > 1 and not args.tiny:  # one process per run: compiled programs do not pile up
        for u, v in jobs:
            subprocess.run([sys.executable, __file__, "--out", str(out), "--variants", v,
                            "--updates", u], check=True)
        print(table(json.loads(dest.read_text())))
        return 0
    # the rows of earlier invocations are kept (a variant run alone adds to them)
    results: dict = json.loads(dest.read_text())["results"] if dest.exists() else {}
    for update, variant in jobs:
        results.setdefault(update, {})[variant] = run(variant, update, out, args.tiny)
        diffs = gaps(results)  # written after every run: a stopped probe keeps its rows
        dest.write_text(json.dumps({"results": results, "differences": diffs}, indent=1)
                        + "\n")
        print(f"{update} / {variant}: done", flush=True)
    if not args.tiny:
        print(table({"results": results, "differences": gaps(results)}))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
