"""Hyperparameter search (``vbl tune``): Optuna proposes trials (ask/tell), the engine runs
each batch of trials x seeds as one zipped sweep (one compilation per static group), and
with ``prune="halving"`` stops the worst trials' learners at each rung of chunks.

A search lives in one folder (``RUN``): Optuna's study in ``study.db`` (SQLite), the
search's settings in ``tune.json``, one vbl run folder per batch (``batch-<k>/``, or
``batch-<k>/rung-<j>/`` per rung with halving), the confirmation run of the best trial on
fresh seeds (``confirm-trial<N>-<seeds>seeds/``), ``summary.json``, ``report.md`` and its
figures. A stopped search continues with ``resume=True``: the batch that was running
resumes from its last checkpoint, and every trial is told once; each batch's sampler is
seeded by the search's seed and the batch, so it asks what an uninterrupted search asks.

Successive halving, batch-synchronous: the batch runs chunks ``0..r0``; each trial reports
its metric (mean over seeds) to Optuna at every chunk; a trial goes on when its value at
the rung's last chunk is among the best ``1/eta`` of every trial's value there (Optuna's
``SuccessiveHalvingPruner`` rule, decided once the whole batch reached the rung), the
others are told ``PRUNED``; the survivors' carries, restored from the rung's checkpoint,
start a run of the next rung (``r0 * eta``, ...), until the program's last chunk. Only the
survivors' learners run on, and the learner-chunks each run logged are counted.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vbl.engine.checkpoint import Checkpoints
from vbl.engine.config import field_default, parse_scalar, parse_value, set_value, split_values
from vbl.engine.errors import EngineError
from vbl.engine.experiment import Experiment
from vbl.engine.jax_setup import engine_precision
from vbl.engine.results import read_json, read_metrics, write_json
from vbl.engine.runfolder import open_run_folder
from vbl.engine.runner import resolve, run_experiment
from vbl.engine.sweep import MAX_SEED, make_plan
from vbl.params import ParamError, get_path, static_paths

__all__ = ["Dim", "parse_space", "tune", "TuneResult", "require_optuna", "SAMPLERS",
           "PRUNERS", "TUNE_FORMAT", "rungs"]

SAMPLERS = ("tpe", "random", "grid")
PRUNERS = ("none", "halving")
TUNE_FORMAT = 1  #: version of ``tune.json``
STUDY = "vbl-tune"  #: the study's name in ``study.db``
_RESUMABLE = ("trials", "confirm_seeds")  # tune.json entries a --resume may change


def require_optuna():
    """The ``optuna`` module; an EngineError saying how to install it otherwise."""
    try:
        import optuna
    except ImportError:
        raise EngineError("vbl tune needs optuna: pip install 'vbl[tune]'") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


@dataclass(frozen=True)
class Dim:
    """One searched parameter: ``kind`` "float" or "int" (``low``..``high``, ``log``) or
    "choice" (``choices``); ``text`` is the SPEC it was parsed from."""

    path: str
    kind: str
    text: str
    low: float | int | None = None
    high: float | int | None = None
    log: bool = False
    choices: tuple = ()

    def distribution(self):
        """The Optuna distribution of this parameter."""
        optuna = require_optuna()
        d = optuna.distributions
        if self.kind == "choice":
            return d.CategoricalDistribution(list(self.choices))
        cls = d.IntDistribution if self.kind == "int" else d.FloatDistribution
        return cls(self.low, self.high, log=self.log)

    def grid(self) -> list[Any]:
        """The values of a grid over this parameter (choices, or every int of a range)."""
        if self.kind == "choice":
            return list(self.choices)
        if self.kind == "int" and not self.log:
            return list(range(int(self.low), int(self.high) + 1))
        raise ParamError(f"--sampler grid needs choices (a,b,c) or an int range; "
                         f"{self.path}={self.text} is a {self.kind} range")


def _number(text: str, what: str) -> int | float:
    v = parse_scalar(text)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ParamError(f"--space {what}: {text!r} is not a number (SPEC: LOW..HIGH, "
                         f"LOW..HIGH:log or a,b,c)")
    return v


def _parse_dim(text: str, config: Any) -> Dim:
    """``"PATH=SPEC"`` -> :class:`Dim` (the path and each value checked on ``config``)."""
    if "=" not in text:
        raise ParamError(f"bad --space {text!r}: use PATH=SPEC with SPEC LOW..HIGH, "
                         f"LOW..HIGH:log or a,b,c, e.g. agent.learning_rate=0.01..1:log")
    path, _, spec = (x.strip() for x in text.partition("="))
    get_path(config, path)  # an unknown path lists the valid ones
    if ".." in spec:
        return _range_dim(text, path, spec, config)
    default = field_default(config, path)
    vals = [parse_value(v, default) for v in split_values(spec)]
    if not spec or any(v == "" for v in vals):
        raise ParamError(f"--space {text!r} has an empty value")
    if any(not isinstance(v, bool | int | float | str) for v in vals):
        raise ParamError(f"--space {text!r}: choices are numbers, true/false or words")
    if len({repr(v) for v in vals}) < len(vals):
        raise ParamError(f"--space {text!r} gives a value twice")
    for v in vals:
        set_value(config, path, v)
    return Dim(path, "choice", spec, choices=tuple(vals))


def _range_dim(text: str, path: str, spec: str, config: Any) -> Dim:
    """The :class:`Dim` of ``LOW..HIGH[:log]``: ints when both ends and the parameter are
    ints."""
    default = field_default(config, path)
    rng, _, flag = spec.partition(":")
    if flag not in ("", "log"):
        raise ParamError(f"--space {text!r}: the only range flag is :log")
    lo_t, _, hi_t = rng.partition("..")
    lo, hi = _number(lo_t, text), _number(hi_t, text)
    if isinstance(default, bool) or not isinstance(default, int | float):
        raise ParamError(f"--space {text!r}: {path} is not a number (give choices a,b,c)")
    ints = isinstance(lo, int) and isinstance(hi, int) and isinstance(default, int)
    if isinstance(default, int) and not ints:
        raise ParamError(f"--space {text!r}: {path} is an int; give int ends")
    if not lo < hi:
        raise ParamError(f"--space {text!r}: LOW must be below HIGH")
    if flag == "log" and lo <= 0:
        raise ParamError(f"--space {text!r}: a :log range needs LOW > 0")
    for v in (lo, hi):
        set_value(config, path, v if ints else float(v))
    return Dim(path, "int" if ints else "float", spec, lo if ints else float(lo),
               hi if ints else float(hi), flag == "log")


def parse_space(texts: Sequence[str] | Mapping[str, str], config: Any) -> dict[str, Dim]:
    """``["PATH=SPEC", ...]`` (or ``{path: SPEC}``) -> ``{path: Dim}``; a bad SPEC, an
    unknown path, a value out of the parameter's range or a path given twice is a
    ParamError (one line)."""
    if isinstance(texts, Mapping):
        texts = [f"{p}={s}" for p, s in texts.items()]
    out: dict[str, Dim] = {}
    for t in texts:
        d = _parse_dim(str(t), config)
        if d.path in out:
            raise ParamError(f"--space {d.path} is given twice")
        out[d.path] = d
    if not out:
        raise ParamError("vbl tune needs at least one --space PATH=SPEC")
    return out


def rungs(num_chunks: int, eta: int, min_chunks: int) -> list[tuple[int, int]]:
    """The spans of chunks of successive halving: ``[0, r0), [r0, r0 eta), ...``, the last
    ending at ``num_chunks``."""
    bounds, r = [], min_chunks
    while r < num_chunks:
        bounds.append(r)
        r *= eta
    bounds.append(num_chunks)
    return list(zip([0] + bounds[:-1], bounds, strict=True))


@dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` returns: the run folder, ``summary`` (``summary.json``), the best
    trial's ``params``, the report's path and the Optuna study."""

    out_dir: Path
    summary: dict[str, Any]
    params: dict[str, Any]
    report: Path
    study: Any


@dataclass
class _Search:
    """A search's settings (``tune.json``) and what running it needs."""

    experiment: Experiment
    space: dict[str, Dim]
    spec: dict[str, Any]
    sets: dict[str, Any]
    metric: str
    rung_metric: str | None
    is_final: bool
    num_chunks: int
    rungs: list[tuple[int, int]]
    out: Path
    echo: Callable[[str], None]
    quiet: bool
    checkpoint_every: int
    command_name: str | None = None

    @property
    def seeds(self) -> int:
        return self.spec["seeds"]


def _metric_names(experiment: Experiment, config: Any, space: dict[str, Dim]
                  ) -> tuple[list[str], list[str], Any]:
    """``(chunk metrics, final metrics, program)`` of the scalar metrics (one number per
    learner) of the program at the space's first values (shapes only, nothing runs)."""
    first = {p: [d.choices[0] if d.kind == "choice" else d.low] for p, d in space.items()}
    with engine_precision():
        group = make_plan(experiment, config, first, 1, 0, zipped=True).groups[0]
        prog = group.program
        keys = jax.ShapeDtypeStruct((1, 2), np.uint32)
        cfg = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), group.configs)
        carry = jax.eval_shape(jax.vmap(prog.init), keys, cfg)
        _, step = jax.eval_shape(jax.vmap(prog.step), carry, cfg)
        fin = jax.eval_shape(jax.vmap(prog.final), carry, cfg, keys) if prog.final else {}
    scalar = lambda m: [k for k, v in m.items() if v.shape == (1,)]  # noqa: E731
    return scalar(step), scalar(fin), prog


def _choose_metric(metric: str | None, prune: str, chunk: list[str], final: list[str],
                   prog) -> tuple[str, bool, str | None]:
    """``(metric, is a final metric, rung metric)``: ``metric``, else the program's
    ``progress_metric``, else its first final metric; halving's rung metric is ``metric``
    when it is a chunk metric, else the ``progress_metric``."""
    if metric is None:
        metric = prog.progress_metric if prog.progress_metric in chunk else (
            final[0] if final else (chunk[0] if chunk else None))
    if metric not in chunk + final:
        have = ", ".join(final + chunk) or "none"
        raise ParamError(f"--metric {metric!r} is not a scalar metric of the program "
                         f"(final or per chunk: {have})")
    is_final = metric in final and metric not in chunk
    rung = None
    if prune == "halving":
        rung = metric if metric in chunk else prog.progress_metric
        if rung not in chunk:
            raise ParamError(f"--prune halving needs a metric per chunk; {metric} is a final "
                             f"metric and the program names no progress_metric")
    return metric, is_final, rung


def _check_counts(trials: Any, batch: Any, sampler: str, prune: str, direction: str,
                  eta: Any, min_chunks: Any, confirm_seeds: Any, seed: Any) -> None:
    for name, v, lo in (("--trials", trials, 1), ("--batch", batch, 1),
                        ("--reduction-factor", eta, 2), ("--min-chunks", min_chunks, 1),
                        ("--confirm-seeds", confirm_seeds, 2)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < lo
                              or v > MAX_SEED):
            raise ParamError(f"{name} must be an int >= {lo}, got {v!r}")
    for name, v, allowed in (("--sampler", sampler, SAMPLERS), ("--prune", prune, PRUNERS),
                             ("--direction", direction, ("maximize", "minimize"))):
        if v not in allowed:
            raise ParamError(f"{name} must be one of {', '.join(allowed)}, got {v!r}")
    if isinstance(seed, int) and not isinstance(seed, bool) and seed >= MAX_SEED:
        raise ParamError(f"--seed must be below {MAX_SEED} (the confirmation run takes "
                         f"--seed + 1)")


def _plan_search(experiment: Experiment, space, *, trials, batch, seeds, metric, direction,
                 sampler, prune, reduction_factor, min_chunks, sets, seed, confirm_seeds,
                 quick, preset) -> tuple[dict, dict, dict, tuple]:
    """Check everything before a folder is written: ``(spec, space, sets, metric info)``."""
    _check_counts(trials, batch, sampler, prune, direction, reduction_factor, min_chunks,
                  confirm_seeds, seed)
    config, _, seeds, _ = resolve(experiment, sets, None, seeds, seed, quick, preset)
    if experiment.make_program is None:
        raise ParamError(f"{experiment.name} runs its own loop (Experiment.run): vbl tune "
                         f"needs an experiment with make_program")
    space = parse_space(space, config) if not (isinstance(space, Mapping) and all(
        isinstance(d, Dim) for d in space.values())) else dict(space)
    both = sorted(set(space) & set(sets or {}))
    if both:
        raise ParamError(f"{both[0]} is both set and searched; drop its --set or --space")
    # the experiment's default sweep is fixed at the config's value: a trial is one point
    sets = dict(sets or {})
    sets.update({p: get_path(config, p) for p in experiment.sweep
                 if p not in space and p not in sets})
    chunk, final, prog = _metric_names(experiment, config, space)
    metric, is_final, rung = _choose_metric(metric, prune, chunk, final, prog)
    statics = set(static_paths(config)) & set(space)
    if prune == "halving" and statics:
        raise ParamError(f"--prune halving needs traced parameters; {sorted(statics)[0]} is "
                         f"static (each value compiles apart): search it with --prune none")
    if sampler == "grid":
        size = math.prod(len(d.grid()) for d in space.values())
        if trials > size:
            raise ParamError(f"--sampler grid: --trials {trials} is more than the grid's "
                             f"{size} points")
    eta = reduction_factor or 3
    r0 = min_chunks or max(1, prog.num_chunks // eta ** 2)
    spec = {"format": TUNE_FORMAT, "experiment": experiment.name, "preset": preset,
            "quick": bool(quick), "space": {p: d.text for p, d in space.items()},
            "sets": {p: json_value(v) for p, v in sets.items()}, "seeds": seeds,
            "seed": seed, "batch": batch, "metric": metric, "direction": direction,
            "sampler": sampler, "prune": prune, "reduction_factor": eta, "min_chunks": r0,
            "trials": trials, "confirm_seeds": confirm_seeds or max(seeds, 8)}
    return spec, space, sets, (metric, is_final, rung, prog.num_chunks)


def json_value(v: Any) -> Any:
    """A config value as JSON writes it (tuples as lists)."""
    return list(v) if isinstance(v, tuple) else v


def tune(experiment: Experiment, space: Sequence[str] | Mapping[str, str], *,
         trials: int, batch: int, seeds: int | None = None, metric: str | None = None,
         direction: str = "maximize", sampler: str = "tpe", prune: str = "none",
         reduction_factor: int | None = None, min_chunks: int | None = None,
         sets: Mapping[str, Any] | None = None, seed: int = 0,
         confirm_seeds: int | None = None, out: str | Path | None = None,
         resume: bool = False, overwrite: bool = False, quick: bool = False,
         preset: str | None = None, quiet: bool | None = True, checkpoint_every: int = 10,
         echo: Callable[[str], None] | None = None,
         command_name: str | None = None) -> TuneResult:
    """Search ``space`` (``["PATH=SPEC", ...]``: ``LOW..HIGH``, ``LOW..HIGH:log``,
    ``a,b,c``) with ``trials`` Optuna trials, ``batch`` at a time, each over ``seeds``
    seeds (base seed ``seed``), for ``metric`` (default: the program's
    ``progress_metric``, else its first final metric; its mean over seeds, at the last
    chunk for a chunk metric) in ``direction``; then run the best trial again on
    ``confirm_seeds`` fresh seeds (base seed ``seed + 1``) and write ``report.md``.

    ``prune="halving"``: successive halving inside each batch (reduction factor
    ``reduction_factor``, default 3; first rung at ``min_chunks`` chunks, default
    ``num_chunks // 9``). ``out``, ``resume``, ``overwrite`` as for ``vbl run`` (a resume
    may raise ``trials``). ``echo`` gets a line per batch and rung; ``command_name``: the
    experiment as the confirmation's ``vbl run`` command names it (default its name; a
    script's path). Everything is checked before the folder is written.
    """
    optuna = require_optuna()
    sets_in = sets
    spec, space, sets, (metric, is_final, rung_metric, chunks) = _plan_search(
        experiment, space, trials=trials, batch=batch, seeds=seeds, metric=metric,
        direction=direction, sampler=sampler, prune=prune,
        reduction_factor=reduction_factor, min_chunks=min_chunks, sets=sets, seed=seed,
        confirm_seeds=confirm_seeds, quick=quick, preset=preset)
    folder = open_run_folder(out, f"{experiment.name}-tune", resume=resume,
                             overwrite=overwrite)
    try:
        _start_spec(folder.path, spec, resume)
        folder.record("tune.json", "study.db")
        s = _Search(experiment, space, spec, sets, metric, rung_metric, is_final, chunks,
                    rungs(chunks, spec["reduction_factor"], spec["min_chunks"])
                    if prune == "halving" else [(0, chunks)], folder.path,
                    echo or (lambda _: None), quiet, checkpoint_every, command_name)
        s.echo(_describe(s))
        fixed = [p for p in experiment.sweep if p not in space and p not in (sets_in or {})]
        if fixed:
            s.echo("fixed at the config's value (the experiment sweeps it; --set or --space "
                   "it): " + ", ".join(f"{p}={s.sets[p]!r}" for p in fixed))
        study = _study(optuna, s)
        t0 = time.perf_counter()
        _search(optuna, study, s, folder)
        from vbl.engine.tune_report import finish  # it imports this module

        return finish(s, study, folder, time.perf_counter() - t0)
    finally:
        folder.release()


def _describe(s: _Search) -> str:
    """What a search does, said before it starts."""
    sp = s.spec
    how = "no pruning" if sp["prune"] == "none" else (
        f"successive halving, 1/{sp['reduction_factor']} go on at chunks "
        + ", ".join(str(last) for _, last in s.rungs[:-1]))
    return (f"{s.experiment.name}: {sp['trials']} trials in batches of {sp['batch']} x "
            f"{s.seeds} seeds ({s.num_chunks} chunks each), sampler {sp['sampler']}, {how}; "
            f"{sp['direction']} {s.metric}; study in {s.out / 'study.db'}")


def _start_spec(path: Path, spec: dict, resume: bool) -> None:
    """Write ``tune.json``; on resume, refuse another search's settings first."""
    f = path / "tune.json"
    if resume and f.exists():
        try:
            old = read_json(f)
        except (OSError, ValueError) as e:
            raise EngineError(f"cannot resume {path}: its tune.json is unreadable ({e})") \
                from None
        diff = sorted(k for k in set(old) | set(spec)
                      if k not in _RESUMABLE and old.get(k) != spec.get(k))
        if diff:
            raise EngineError(f"cannot resume {path}: it was searched with other settings "
                              f"({', '.join(diff)}); use the same options (only --trials and "
                              f"--confirm-seeds may change), or --overwrite / another --out")
    elif resume and (any(path.glob("batch-*")) or (path / "config.json").exists()):
        raise EngineError(f"cannot resume {path}: it holds no search (no tune.json); pick "
                          f"another --out")
    write_json(f, spec)


def _sampler(optuna, s: _Search, k: int):
    """The sampler that asks batch ``k``'s trials, seeded by the search's seed and ``k``:
    a stopped and resumed search asks what an uninterrupted one asks."""
    seed = (s.spec["seed"] * 1_000_003 + k) % 2**32
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if s.spec["sampler"] == "grid":  # its seed orders the grid: one for every batch
            return optuna.samplers.GridSampler({p: d.grid() for p, d in s.space.items()},
                                               seed=s.spec["seed"])
        if s.spec["sampler"] == "random":
            return optuna.samplers.RandomSampler(seed=seed)
        return optuna.samplers.TPESampler(seed=seed, constant_liar=True)


def _study(optuna, s: _Search):
    """The study in ``study.db`` (created, or loaded to resume)."""
    storage = optuna.storages.RDBStorage(f"sqlite:///{(s.out / 'study.db').absolute()}")
    return optuna.create_study(storage=storage, study_name=STUDY,
                               sampler=_sampler(optuna, s, 0),
                               direction=s.spec["direction"], load_if_exists=True)


def _search(optuna, study, s: _Search, folder) -> None:
    """Finish the batch a stopped search left running, then ask and run batches until the
    study holds ``trials`` trials that ran."""
    states = optuna.trial.TrialState
    running: dict[int, list] = {}
    for t in study.get_trials(deepcopy=False):
        if t.state == states.RUNNING:
            if "batch" in t.user_attrs:
                running.setdefault(t.user_attrs["batch"], []).append(t)
            else:  # asked, never run: a stop between ask and the batch's record
                _tell(study, t.number, state=states.FAIL)
    for k in sorted(running):
        members = [t for t in study.get_trials(deepcopy=False)
                   if t.user_attrs.get("batch") == k]
        _run_batch(optuna, study, s, folder, k, sorted(members, key=lambda t: t.number))
    dists = {p: d.distribution() for p, d in s.space.items()}
    while True:
        done = [t for t in study.get_trials(deepcopy=False) if "batch" in t.user_attrs]
        left = s.spec["trials"] - len(done)
        if left <= 0:
            return
        k = 1 + max((t.user_attrs["batch"] for t in done), default=-1)
        study.sampler = _sampler(optuna, s, k)
        asked = []
        for _ in range(min(left, s.spec["batch"])):
            trial = study.ask(fixed_distributions=dists)
            trial.set_user_attr("batch", k)
            asked.append(trial.number)
        members = [t for t in study.get_trials(deepcopy=False) if t.number in asked]
        _run_batch(optuna, study, s, folder, k, members)


def _batch_dir(s: _Search, k: int, j: int) -> Path:
    base = s.out / f"batch-{k}"
    return base if len(s.rungs) == 1 else base / f"rung-{j}"


def _run_batch(optuna, study, s: _Search, folder, k: int, members: list) -> None:
    """Run batch ``k`` (its trials ``members``) rung by rung; report, prune and tell."""
    folder.record(f"batch-{k}")
    alive, prev = list(members), None
    for j, (first, last) in enumerate(s.rungs):
        if not alive:
            break
        out = _batch_dir(s, k, j)
        zipped = {p: [t.params[p] for t in alive] for p in s.space}
        start = None if prev is None else _carry_from(*prev, s.seeds)
        s.echo(f"batch {k}: trials {', '.join(str(t.number) for t in alive)} x {s.seeds} "
               f"seeds, chunks {first}-{last - 1}" + (f" (rung {j})" if len(s.rungs) > 1
                                                       else ""))
        res = run_experiment(s.experiment, sets=s.sets, sweep=zipped, zipped=True,
                             seeds=s.seeds, base_seed=s.spec["seed"], out=out,
                             resume=out.exists(), quick=s.spec["quick"],
                             preset=s.spec["preset"], quiet=s.quiet, plots=False,
                             report=False, checkpoint_every=s.checkpoint_every,
                             span=None if len(s.rungs) == 1 else (first, last),
                             start_carry=start)
        for p, t in enumerate(alive):
            _report_chunks(optuna, study, s, t, res, p, first, last)
        if last < s.num_chunks:
            keep = _rung(optuna, study, s, alive, last)
            prev = (out, [i for i, t in enumerate(alive) if t.number in keep])
            alive = [t for t in alive if t.number in keep]
            continue
        for p, t in enumerate(alive):
            if _finished(study, t):
                continue
            vals = _objective(s, res, p)
            tr = optuna.trial.Trial(study, t._trial_id)
            tr.set_user_attr("per_seed", [float(v) for v in vals])
            tr.set_user_attr("run", str(out.relative_to(s.out)))
            tr.set_user_attr("point", p)
            mean = float(np.mean(vals))
            _tell(study, t.number, mean if math.isfinite(mean) else None,
                  state=None if math.isfinite(mean) else optuna.trial.TrialState.FAIL)


def _tell(study, number: int, value: float | None = None, state=None) -> None:
    """``study.tell``; the grid sampler stops the study when its grid is done, which
    outside ``optimize`` raises after the trial is stored (the search ends by count)."""
    try:
        study.tell(number, value, state=state)
    except RuntimeError as e:
        if "Study.stop" not in str(e):
            raise


def _finished(study, t) -> bool:
    """Whether trial ``t`` is finished in the storage now (told by this or an earlier,
    stopped run of the search)."""
    return study._storage.get_trial(t._trial_id).state.is_finished()


def _objective(s: _Search, res, p: int) -> np.ndarray:
    """Trial ``p``'s per-seed values of the search's metric in a finished run (a chunk
    metric's at the point's last logged chunk)."""
    if s.is_final:
        return np.asarray(res.final[s.metric][p], np.float64)
    a = np.asarray(res.curves[s.metric][p], np.float64)  # (chunks, seeds), NaN past its end
    logged = np.flatnonzero(~np.all(np.isnan(a), axis=1))
    return a[logged[-1]] if len(logged) else a[-1]


def _report_chunks(optuna, study, s: _Search, t, res, p: int, first: int, last: int
                   ) -> None:
    """With halving, report trial ``t``'s (point ``p`` of ``res``) rung metric, its mean
    over seeds, at every chunk ``first..last - 1`` (step = chunks done) that the study does
    not hold yet (a resumed rung reports only what its stopped run did not)."""
    frozen = study._storage.get_trial(t._trial_id)  # as stored now
    if s.rung_metric is None or frozen.state.is_finished():
        return
    trial = optuna.trial.Trial(study, t._trial_id)
    curve = np.asarray(res.curves[s.rung_metric][p], np.float64)
    for c in range(first, last):
        if c + 1 not in frozen.intermediate_values:
            v = float(np.mean(curve[c]))
            trial.report(v if math.isfinite(v) else float("nan"), c + 1)


def _rung(optuna, study, s: _Search, alive: list, last: int) -> set[int]:
    """Keep the trials whose value at step ``last`` is among the best ``1/eta`` of every
    trial's value there, tell the others ``PRUNED``; the kept trials' numbers."""
    at = {t.number: t.intermediate_values[last] for t in study.get_trials(deepcopy=False)
          if last in t.intermediate_values}
    competing = sorted(v for v in at.values() if math.isfinite(v))
    n_keep = max(1, len(competing) // s.spec["reduction_factor"])
    best = s.spec["direction"] == "maximize"
    bar = (competing[-n_keep] if best else competing[n_keep - 1]) if competing else None
    keep = set()
    for t in alive:
        v = at.get(t.number, float("nan"))
        if bar is not None and math.isfinite(v) and (v >= bar if best else v <= bar):
            keep.add(t.number)
        elif not _finished(study, t):
            _tell(study, t.number, state=optuna.trial.TrialState.PRUNED)
    s.echo(f"  rung at chunk {last}: {len(keep)} of {len(alive)} trials go on")
    return keep


def _carry_from(prev: Path, keep: list[int], seeds: int) -> Callable[[Any], Any]:
    """``start_carry`` of a rung's run: the carries of the kept points (indices into the
    previous rung's points) at the previous rung's last checkpoint."""
    def load(like):
        spec = read_json(prev / "config.json")
        n_prev = len(next(iter(spec["sweep"].values()))) * seeds
        like_prev = jax.tree.map(lambda x: np.zeros((n_prev,) + x.shape[1:], x.dtype), like)
        ckpts = Checkpoints(prev / "checkpoints", spec["fingerprint"])
        try:
            tree, _ = ckpts.restore(spec["span"][1], like_prev)
        finally:
            ckpts.close()
        rows = np.concatenate([np.arange(p * seeds, (p + 1) * seeds) for p in keep])
        return jax.tree.map(lambda x: x[rows], tree)
    return load


def learner_chunks(run_dir: Path) -> int:
    """Learner-chunks a run folder logged: the seeds of its ``metrics.jsonl`` chunk rows."""
    return sum(len(next(iter(r["metrics"].values()))["per_seed"])
               for r in read_metrics(Path(run_dir) / "metrics.jsonl")
               if isinstance(r.get("chunk"), int) and r.get("metrics"))

