"""The end of a ``vbl tune`` search: the best trial run again on fresh seeds, the compute
the search used, ``summary.json``, the figures (optimisation history, Optuna's parameter
importances, drawn with matplotlib) and ``report.md``."""

from __future__ import annotations

import math
import shlex
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.errors import EngineError
from vbl.engine.plots import is_rate, pyplot
from vbl.engine.results import write_json
from vbl.engine.runner import run_experiment
from vbl.engine.tune import TuneResult, json_value, learner_chunks, require_optuna
from vbl.params import get_path
from vbl.stats import bounded_ci95, mean_ci95, welch_ci95

__all__ = ["finish", "interval", "confirm_command"]


def interval(values: Any, metric: str) -> dict[str, Any]:
    """Mean and 95 % interval over seeds of ``values`` (a rate's kept in [0, 1])."""
    v = np.asarray(values, np.float64)
    mean, half = mean_ci95(v)
    lo, hi = mean - half, mean + half
    if is_rate(metric) and half == half:
        b = bounded_ci95(v, 0.0, 1.0)
        lo, hi = (b[1], b[2]) if b is not None else (float("nan"), float("nan"))
    return {"mean": mean, "ci95": half, "lower": lo, "upper": hi, "seeds": int(v.size),
            "per_seed": [float(x) for x in v]}


def _cli_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list | tuple):
        return "(" + ",".join(_cli_value(x) for x in v) + ")"
    return repr(v) if isinstance(v, float) else str(v)


def confirm_command(s, params: dict[str, Any]) -> str:
    """The ``vbl run`` command of the confirmation run (into a folder of its own)."""
    words = ["vbl", "run", s.command_name or s.experiment.name]
    if s.spec["quick"]:
        words.append("--quick")
    if s.spec["preset"]:
        words += ["--preset", s.spec["preset"]]
    for p, v in {**params, **s.sets}.items():
        words += ["--set", f"{p}={_cli_value(v)}"]
    words += ["--seeds", str(s.spec["confirm_seeds"]), "--seed", str(s.spec["seed"] + 1)]
    return " ".join(shlex.quote(w) for w in words)


def _confirm(s, folder, name: str, what: str, params: dict[str, Any]) -> dict[str, Any]:
    """Run ``params`` (the best trial's values, or ``{}`` for the config's own) on
    ``confirm_seeds`` fresh seeds (base seed ``seed + 1``) into the folder ``name`` (a
    resumed search whose best trial or confirmation seeds changed writes a new folder):
    its metric's values and interval."""
    out = s.out / name
    folder.record(name)
    s.echo(f"confirmation: {what} on {s.spec['confirm_seeds']} fresh seeds")
    res = run_experiment(s.experiment, sets={**s.sets, **params},
                         seeds=s.spec["confirm_seeds"], base_seed=s.spec["seed"] + 1,
                         out=out, resume=out.exists(), quick=s.spec["quick"],
                         preset=s.spec["preset"], quiet=s.quiet, plots=True,
                         checkpoint_every=s.checkpoint_every)
    vals = res.final[s.metric][0] if s.is_final else res.curves[s.metric][0, -1]
    return {**interval(vals, s.metric), "base_seed": s.spec["seed"] + 1,
            "run": name, "command": confirm_command(s, params),
            "params": {p: json_value(get_path(res.config, p)) for p in s.space}}


def _compute(s, trials: list) -> dict[str, Any]:
    """Learner-chunks the batches' runs logged, beside a full grid of the same trials."""
    ran = sum(learner_chunks(p.parent) for p in s.out.glob("batch-*/**/metrics.jsonl"))
    full = len(trials) * s.seeds * s.num_chunks
    return {"learner_chunks": ran, "full_grid_learner_chunks": full,
            "saved": 1.0 - ran / full if full else 0.0,
            "rungs": [list(r) for r in s.rungs]}


def _importances(optuna, study) -> tuple[dict[str, float], str | None]:
    try:
        with warnings.catch_warnings():  # a warning about few trials: the values say it
            warnings.simplefilter("ignore")
            return dict(optuna.importance.get_param_importances(study)), None
    except Exception as e:  # noqa: BLE001 - too few or constant trials: the report says so
        return {}, f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"


def _figures(s, optuna, trials: list, importances: dict[str, float],
             confirm: dict[str, Any]) -> list[str]:
    """``history.png`` (each trial's value, pruned trials at their last rung, the best so
    far, the best trial's confirmation on fresh seeds) and ``importance.png`` (Optuna's
    importances)."""
    plt = pyplot()
    states = optuna.trial.TrialState
    done = [t for t in trials if t.state == states.COMPLETE]
    pruned = [t for t in trials if t.state == states.PRUNED and t.intermediate_values]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot([t.number for t in done], [t.value for t in done], "o", label="trial")
    if pruned:
        ax.plot([t.number for t in pruned],
                [t.intermediate_values[t.last_step] for t in pruned], "x", color="0.5",
                label="pruned (value at its last rung)")
    pick = max if s.spec["direction"] == "maximize" else min
    best, run = [], None
    for t in sorted(done, key=lambda t: t.number):
        run = t.value if run is None else pick(run, t.value)
        best.append((t.number, run))
    if best:
        ax.step(*zip(*best, strict=True), where="post", color="C3", label="best so far")
    if math.isfinite(confirm["lower"]) and math.isfinite(confirm["upper"]):
        ax.axhspan(confirm["lower"], confirm["upper"], color="C2", alpha=0.2, lw=0)
    ax.axhline(confirm["mean"], color="C2", lw=1,
               label=f"best trial on {confirm['seeds']} fresh seeds (95 % CI)")
    ax.set(xlabel="trial", ylabel=f"{s.metric} (mean over {s.seeds} seeds)",
           title=f"{s.experiment.name}: optimisation history")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(s.out / "history.png", dpi=110)
    plt.close(fig)
    names = ["history.png"]
    if importances:
        fig, ax = plt.subplots(figsize=(6, 1.2 + 0.45 * len(importances)))
        items = list(importances.items())[::-1]
        ax.barh([k for k, _ in items], [v for _, v in items])
        ax.set(xlabel="importance (Optuna, normalised)", title="parameter importances")
        fig.tight_layout()
        fig.savefig(s.out / "importance.png", dpi=110)
        plt.close(fig)
        names.append("importance.png")
    return names


def finish(s, study, folder, wall: float) -> TuneResult:
    """Confirm the best trial, then write ``summary.json``, the figures and
    ``report.md``."""
    optuna = require_optuna()
    states = optuna.trial.TrialState
    trials = [t for t in study.get_trials() if "batch" in t.user_attrs]
    done = [t for t in trials if t.state == states.COMPLETE]
    if not done:
        raise EngineError(f"no trial of {s.out} finished with a finite {s.metric}; nothing "
                          f"to confirm")
    best = study.best_trial
    params = {p: best.params[p] for p in s.space}
    search = interval(best.user_attrs["per_seed"], s.metric)
    seeds = s.spec["confirm_seeds"]
    confirm = _confirm(s, folder, f"confirm-trial{best.number}-{seeds}seeds", "the best trial",
                       params)
    defaults = _confirm(s, folder, f"confirm-defaults-{seeds}seeds",
                        "the config's values of the searched parameters", {})
    diff, half = welch_ci95(search["per_seed"], confirm["per_seed"])
    gain, gain_half = welch_ci95(confirm["per_seed"], defaults["per_seed"])
    importances, why = _importances(optuna, study)
    summary = {
        "experiment": s.experiment.name, "metric": s.metric,
        "direction": s.spec["direction"], "best_trial": best.number, "params": params,
        "search": {**search, "run": best.user_attrs.get("run"),
                   "point": best.user_attrs.get("point"), "base_seed": s.spec["seed"]},
        "confirmation": confirm, "search_minus_confirmation": {"diff": diff, "ci95": half},
        "defaults": defaults,
        "confirmation_minus_defaults": {"diff": gain, "ci95": gain_half},
        "trials": {"ran": len(trials), "complete": len(done),
                   "pruned": sum(t.state == states.PRUNED for t in trials),
                   "failed": sum(t.state == states.FAIL for t in trials)},
        "compute": _compute(s, trials), "importances": importances,
        "importances_note": why, "wall_time_s": wall,
        "history": [{"trial": t.number, "state": t.state.name, "value": t.value,
                     "params": t.params, "batch": t.user_attrs["batch"],
                     "last_chunk": t.last_step} for t in trials]}
    folder.record("summary.json", "report.md", "history.png", "importance.png")
    write_json(s.out / "summary.json", summary)  # NaN and infinities as null
    figures = _figures(s, optuna, trials, importances, confirm)
    report = s.out / "report.md"
    report.write_text(_markdown(s, summary, figures))
    return TuneResult(s.out, summary, params, report, study)


def _num(x: float) -> str:
    return "nan" if not math.isfinite(x) else f"{x:.4g}"


def _cell(iv: dict[str, Any]) -> str:
    if not math.isfinite(iv["ci95"]):
        return f"{_num(iv['mean'])} (one seed, no interval)"
    return f"{_num(iv['mean'])} ± {_num(iv['ci95'])} [{_num(iv['lower'])}, {_num(iv['upper'])}]"


def _markdown(s, sm: dict[str, Any], figures: list[str]) -> str:
    c, comp, base = sm["confirmation"], sm["compute"], sm["defaults"]
    params = ", ".join(f"`{p}` = {v!r}" for p, v in sm["params"].items())
    d, g = sm["search_minus_confirmation"], sm["confirmation_minus_defaults"]
    lines = [
        f"# vbl tune: {s.experiment.name}", "",
        f"{sm['trials']['ran']} trials ({sm['trials']['complete']} complete, "
        f"{sm['trials']['pruned']} pruned, {sm['trials']['failed']} without a finite "
        f"value) in batches of {s.spec['batch']} x {s.seeds} "
        f"seeds, sampler {s.spec['sampler']}, pruning {s.spec['prune']}; "
        f"{s.spec['direction']} `{s.metric}` (mean over seeds"
        f"{'' if s.is_final else ', last chunk'}). Space: "
        + ", ".join(f"`{p}` = {t}" for p, t in s.spec["space"].items()) + ".", "",
        f"**Best trial {sm['best_trial']}**: {params}.", "",
        "| estimate | seeds (base seed) | mean ± 95 % CI [interval] | run |",
        "|---|---|---|---|",
        f"| the search's (the winner of {sm['trials']['ran']} trials) | "
        f"{sm['search']['seeds']} ({sm['search']['base_seed']}) | {_cell(sm['search'])} | "
        f"{sm['search']['run']} |",
        f"| confirmation on fresh seeds | {c['seeds']} ({c['base_seed']}) | {_cell(c)} | "
        f"{c['run']} |",
        "| the config's values ("
        + ", ".join(f"`{p}` = {v!r}" for p, v in base["params"].items())
        + f") on the same fresh seeds | {base['seeds']} ({base['base_seed']}) | "
        f"{_cell(base)} | {base['run']} |", "",
        f"Search minus confirmation: {_num(d['diff'])} ± {_num(d['ci95'])} (Welch 95 %). "
        "The search's estimate of its winner is the best of many noisy estimates, biased in "
        "the winner's favour on average (the winner's curse); the confirmation, on seeds "
        "the search never saw, is the estimate to quote.", "",
        f"Confirmation minus the config's values: {_num(g['diff'])} ± {_num(g['ci95'])} "
        "(Welch 95 %, the same seeds): what the search gained over the defaults.",
        "", f"Reproduce the confirmation run: `{c['command']}`", "",
        f"Compute: {comp['learner_chunks']:,} learner-chunks run, a full grid of the same "
        f"trials {comp['full_grid_learner_chunks']:,} ({100 * comp['saved']:.1f} % saved; "
        f"rungs of chunks {comp['rungs']}); wall time {sm['wall_time_s']:.1f} s.", ""]
    lines += [f"![{Path(f).stem}]({f})" for f in figures]
    if sm["importances_note"]:
        lines += ["", f"Parameter importances: not computable ({sm['importances_note']})."]
    elif sm["importances"]:
        lines += ["", f"Parameter importances (Optuna's, from the "
                  f"{sm['trials']['complete']} complete trials): " + ", ".join(
            f"`{k}` {v:.2f}" for k, v in sm["importances"].items()) + "."]
    sign = -1.0 if s.spec["direction"] == "maximize" else 1.0
    rows = sorted(sm["history"], key=lambda h: (
        h["state"] != "COMPLETE", -(h["last_chunk"] or 0),
        sign * h["value"] if h["value"] is not None and math.isfinite(h["value"])
        else math.inf))
    lines += ["", "| trial | batch | state | last chunk | value | params |",
              "|---|---|---|---|---|---|"]
    lines += [f"| {h['trial']} | {h['batch']} | {h['state']} | {h['last_chunk']} | "
              f"{_num(h['value']) if h['value'] is not None else '-'} | "
              + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                          for k, v in h["params"].items()) + " |" for h in rows]
    return "\n".join(lines) + "\n"
