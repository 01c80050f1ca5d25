"""Tables 1 and 3 as engine programs: one learner collects its data sets and identifies them.

One learner (= one seed) of :func:`identification_program`:

* ``init``: the carry holds the learner's key and room for its data sets;
* ``step`` (the only chunk): one data set per scenario (a table row, or a test set of the
  model-swap test), scenario ``s`` from ``fold_in(key, s)``
  (:func:`vbl.envs.collect.collect_scenarios`); the data sets stay in the carry, so the
  engine's checkpoint holds them;
* ``final``: identifies every row's data set with :func:`identify_one` (the jittable core of
  :func:`vbl.sysid.identify`, :func:`vbl.sysid.lag.identify_one_fit`: the same CVA fits,
  order cap and lag rule, without its host-side input checks, which cannot run on traced
  data; the config's ``check()``
  validates what can be checked before the run: the scenarios and the record length) and
  reports l, n, log det R and AIC of each row as per-seed metrics ``<q>_<row>``, and the
  swap test's ``swap_<data>_data_<model>_model``.

The engine vmaps the program over sweep points x seeds, shards the learners over devices and
checkpoints them, as for every other experiment. The rest of this module turns a run's
per-seed metrics into the table cells (:func:`row_stats`, :func:`row_markdown`,
:func:`identification_cells`) and holds the collection scenarios of both tables.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.engine.experiment import Program, ReportSection, RunResult
from vbl.engine.plots import point_label
from vbl.engine.report import seeds_cell
from vbl.envs.collect import CollectData, CollectParams, collect_scenarios, object_outputs
from vbl.envs.noise import NoiseParams
from vbl.envs.shoot_pass import OBS_SLICES, ShootPassParams
from vbl.params import ParamError, param, validate
from vbl.sysid import CVAModel, min_length
from vbl.sysid.lag import identify_one_fit, n_cap_for
from vbl.sysid.params import CVAParams

__all__ = ["RowSetup", "TABLE1_ROWS", "OBJECT", "QUANTITIES", "table1_scenarios",
           "table3_scenarios", "slug", "check_scenarios", "identify_one",
           "identification_program", "row_stats", "row_markdown", "claims_markdown",
           "identification_cells", "swap_markdown", "point_report"]

TABLE1_ROWS = ("goal", "ball", "random walk", "move to the ball")
OBJECT = {"goal": "goal", "ball": "ball", "random walk": "other", "move to the ball": "other"}
"""The identified object of each Table 1 row (its outputs: :func:`vbl.envs.collect.id_outputs`)."""
QUANTITIES = ("l", "n", "logdet_R", "aic")
"""The per-seed final metrics of a row ``<q>_<row>``: lag, AIC order, log det R, AIC."""
F64 = jnp.float64


@struct.dataclass
class RowSetup:
    """Per-row changes to the common collection setup (our tuning, documented)."""

    goal_min_dist: float = param(2.0, doc="(a) observer keeps the goal centre at least this "
                                 "far", unit="m", ge=0.0)
    goal_max_dist: float = param(3.5, doc="(a) ... and at most this far", unit="m", gt=0.0)
    ball_kick_prob: float = param(0.1, doc="(b) kick probability per step of a slow ball",
                                  ge=0.0, le=1.0)
    other_kick_prob: float = param(0.02, doc="(c, d) kick probability per step of a slow "
                                   "ball (the move-to-ball robot chases it)", ge=0.0, le=1.0)


def slug(row: str) -> str:
    """A row's name in metric names (``"move to the ball"`` -> ``"move_to_the_ball"``)."""
    return row.replace(" ", "_").replace("-", "_")


def table1_scenarios(c: CollectParams, r: RowSetup) -> dict[str, CollectParams]:
    """The four collection scenarios of Table 1 (keyed by row name) from the common setup
    ``c`` and the row changes ``r`` (values may be traced)."""
    return {
        "goal": c.replace(focus="goal", other_behaviour="stationary",
                          min_dist=r.goal_min_dist, max_dist=r.goal_max_dist),
        "ball": c.replace(focus="ball", other_behaviour="stationary",
                          kick_prob=r.ball_kick_prob),
        "random walk": c.replace(focus="other", other_behaviour="random_walk",
                                 kick_prob=r.other_kick_prob),
        "move to the ball": c.replace(focus="other", other_behaviour="move_to_ball",
                                      kick_prob=r.other_kick_prob),
    }


def _observer(base: CollectParams, bodies: ShootPassParams, who: str) -> CollectParams:
    """``base`` seen by the shooter or the passer (its camera; the passer's body too)."""
    if who == "shooter":
        return base.replace(camera=bodies.shooter_camera)
    return base.replace(camera=bodies.passer_camera,
                        world=base.world.replace(four_wheel=bodies.passer_body))


def table3_scenarios(c: CollectParams, r: RowSetup, bodies: ShootPassParams,
                     noise: NoiseParams) -> dict[str, CollectParams]:
    """Table 3's scenarios ``{"<view>_<object>": params}``: Table 1's ball, goal (shooter
    only) and move-to-ball ("other") rows with ``noise``, seen by the shooter and by the
    passer (``bodies``), then the noise-free rows seen by the shooter (view ``noise_free``)."""
    t1 = table1_scenarios(c, r)
    rows = {"ball": "ball", "goal": "goal", "other": "move to the ball"}
    out = {}
    for who, objs in (("shooter", ("ball", "goal", "other")), ("passer", ("ball", "other"))):
        out.update({f"{who}_{o}": _observer(t1[rows[o]].replace(noise=noise), bodies, who)
                    for o in objs})
    out.update({f"noise_free_{o}": _observer(t1[rows[o]], bodies, "shooter")
                for o in ("goal", "ball", "other")})
    return out


def check_scenarios(scenarios: Mapping[str, CollectParams], objects: Mapping[str, str],
                    ident: CVAParams) -> None:
    """A config's ``check()``: every scenario validates, and its records are long enough for
    the largest lag of ``ident`` with its object's outputs (ParamError otherwise)."""
    for name, sc in scenarios.items():
        validate(sc, prefix=f"scenario {name}: ")
    lag = max(ident.lags())
    for name, obj in objects.items():
        q = OBS_SLICES[obj].stop - OBS_SLICES[obj].start
        need = min_length(lag, ident.horizon_for(lag), 2, q, ident.min_samples_factor)
        if scenarios[name].num_steps < need:
            raise ParamError(f"collect.num_steps={scenarios[name].num_steps} is too short to "
                             f"identify {name} ({obj}, q={q}) up to lag {lag}: need >= {need}")


def identify_one(u, y, ident: CVAParams) -> tuple[dict[str, jax.Array], CVAModel]:
    """CVA, AIC order and lag on one data set ``u (N, m)``, ``y (N, q)`` (pure; jit/vmap-able).

    :func:`vbl.sysid.lag.identify_one_fit` (the jittable core of :func:`vbl.sysid.identify`:
    its fits, order cap and lag rule, without its input checks) packaged as ``({"l", "n",
    "logdet_R", "aic"}`` scalars, the filtering model at the chosen lag, history length
    ``max(ident.lags())``).
    """
    m, q = u.shape[-1], y.shape[-1]
    cap = n_cap_for(ident, m, q)
    fit, j, logdet, aic = identify_one_fit(u, y, ident, n_cap=cap)
    lag, n = jnp.asarray(ident.lags(), jnp.int32)[j], fit.n.astype(jnp.int32)
    model = CVAModel(U=fit.U * (jnp.arange(cap) < n)[:, None], A=fit.A, B=fit.B, C=fit.C,
                     D=fit.D, R=fit.R, n=n, lag=lag, u_mean=fit.u_mean, u_scale=fit.u_scale,
                     y_mean=fit.y_mean, y_scale=fit.y_scale)
    return {"l": lag, "n": n, "logdet_R": logdet[j], "aic": aic[j]}, model


def _pred_logdet(model: CVAModel, u, y):
    """log det of the one-step prediction-error covariance of ``model`` on (u (N,m),
    y (N,q)), over t >= the model's history length (one data set)."""
    def body(hist, uy):
        ut, yt = uy
        return model.update_history(hist, ut, yt), yt - model.predict(hist, ut)

    _, e = jax.lax.scan(body, model.init_history(), (u, y))
    e = e[model.history_length:]
    e = e - e.mean(0)
    return jnp.linalg.slogdet(e.T @ e / e.shape[0])[1]


@struct.dataclass
class DataSets:
    """One learner's carry: its key (uint32[2]) and one data set per scenario (S, N, ...)."""

    key: jax.Array
    data: CollectData


def identification_program(cfg: Any, scenarios: Callable[[Any], dict[str, CollectParams]],
                           objects: Mapping[str, str],
                           swap: Mapping[str, tuple[str, str]] | None = None) -> Program:
    """The program of one learner (module docstring); ``cfg`` has ``ident`` (CVAParams) and
    ``y_unit`` (px).

    ``scenarios(config)``: ``{name: CollectParams}`` of one learner (names are metric
    suffixes); ``objects``: ``{name: object}`` of the scenarios to identify (the others are
    test data); ``swap``: ``{observer: (training row, test scenario)}``: each observer's model
    (identified on its training row) predicts every observer's test data.
    """
    names, swap = list(scenarios(cfg)), dict(swap or {})
    for name in [*objects, *(s for pair in swap.values() for s in pair)]:
        if name not in names:
            raise ValueError(f"{name!r} is not a scenario; scenarios: {names}")

    def init(key, c):
        shape = jax.eval_shape(lambda k: collect_scenarios(k, list(scenarios(c).values())), key)
        return DataSets(key, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shape))

    def step(carry, c):
        data = collect_scenarios(carry.key, list(scenarios(c).values()))
        return carry.replace(data=data), {"episodes": jnp.float32(len(names))}

    def final(carry, c, key):
        d, out, models = carry.data, {}, {}
        for obj in sorted(set(objects.values())):
            idx = [i for i, name in enumerate(names) if objects.get(name) == obj]
            y = object_outputs(d.y(obj)[np.asarray(idx)].astype(F64), obj, c.y_unit.astype(F64))
            res, model = jax.vmap(lambda u_, y_: identify_one(u_, y_, c.ident))(
                d.u[np.asarray(idx)].astype(F64), y)
            for k, i in enumerate(idx):
                out.update({f"{q}_{slug(names[i])}": v[k] for q, v in res.items()})
                models[names[i]] = jax.tree.map(lambda a, k=k: a[k], model)
        for who, (_, test) in swap.items():
            i = names.index(test)
            for by, (train, _) in swap.items():
                y = object_outputs(d.y(objects[train])[i].astype(F64), objects[train],
                                   c.y_unit.astype(F64))
                out[f"swap_{who}_data_{by}_model"] = _pred_logdet(models[train],
                                                                  d.u[i].astype(F64), y)
        return out

    return Program(init=init, step=step, num_chunks=1, final=final)


def row_stats(final: Mapping[str, Any], point: int, row: str) -> dict:
    """Per-seed values, mean, population std and (for l and n) the mode over seeds of each
    quantity of ``row`` at sweep point ``point`` of a run's ``final`` metrics."""
    out = {}
    for q in QUANTITIES:
        a = np.asarray(final[f"{q}_{slug(row)}"][point], np.float64)
        out[q] = {"values": a, "mean": float(a.mean()), "std": float(a.std())}
        if q in ("l", "n") and np.isfinite(a).all():
            out[q]["mode"] = int(np.bincount(a.astype(int)).argmax())
    return out


def row_markdown(cells: list[str], s: dict, paper: tuple | None, mode: bool = False) -> str:
    """One table row: the leading ``cells``, then l, n (with their modes if ``mode``),
    log det R, AIC as mean ± 95 % interval over seeds (one data set each), then the paper's
    l / n / log det R / AIC."""
    def ms(k, f):
        extra = f" (mode {s[k]['mode']})" if mode and "mode" in s[k] else ""
        return seeds_cell(s[k]["values"], fmt=f) + extra

    p = " / ".join(str(x) for x in paper) if paper else "-"
    return "| " + " | ".join([*cells, ms("l", ".2f"), ms("n", ".2f"), ms("logdet_R", ".3f"),
                             ms("aic", ".0f"), p]) + " |"


def claims_markdown(checks: dict[str, str]) -> list[str]:
    """The lines of a ``| claim | holds |`` table (after a blank line); the verdicts are
    :func:`vbl.engine.report.claim` texts (95 % intervals over seeds)."""
    return ["", "| claim | holds (95 % interval of the difference over seeds) |", "|---|---|"] + [
        f"| {c} | {v} |" for c, v in checks.items()]


def identification_cells(final: Mapping[str, Any], point: int, row: str) -> str:
    """``l / n / log det R / AIC`` of ``row`` at ``point``, each mean ± 95 % interval over
    seeds."""
    return " / ".join(seeds_cell(final[f"{q}_{slug(row)}"][point], fmt=f) for q, f in (
        ("l", ".2f"), ("n", ".2f"), ("logdet_R", ".2f"), ("aic", ".0f")))


def swap_markdown(final: Mapping[str, Any], point: int, observers: tuple[str, ...]) -> list[str]:
    """The lines of the model-swap table (per-seed ``swap_<data>_data_<model>_model``)."""
    lines = ["", "Model swap (ball; log det of the one-step prediction-error covariance on "
             "each observer's held-out data set, mean ± 95 % interval over seeds):", "",
             "| data | model | log det |", "|---|---|---|"]
    for data in observers:
        for model in sorted(observers, key=lambda o: o != data):
            a = np.asarray(final[f"swap_{data}_data_{model}_model"][point], np.float64)
            lines.append(f"| {data} data | {model} model | {seeds_cell(a, fmt='.3f')} |")
    return lines


def point_report(table: Callable[[RunResult, int], str]) -> Callable[[RunResult], ReportSection]:
    """An experiment's ``report``: ``table(res, point)`` for each sweep point (under the
    point's values when there is a sweep)."""
    def report(res: RunResult) -> ReportSection:
        parts = [(f"**{point_label(pt)}**\n\n" if res.sweep else "") + table(res, i)
                 for i, pt in enumerate(res.points)]
        return ReportSection(markdown="\n\n".join(parts))

    return report
