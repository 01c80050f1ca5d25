"""Tables 1 and 3: identification of observed agents from many data sets at once.

The collection scenarios of Table 1 (goal, ball, a random walker, a robot that moves to the
ball; :mod:`vbl.envs.collect`), the statistics of an identification over data sets (l, n,
log det R, AIC), the table cells, and Table 3's model-swap test (a model's one-step
prediction error on another observer's data).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.engine.experiment import ReportSection, RunResult
from vbl.engine.report import stat_cell
from vbl.envs.collect import CollectParams, id_outputs
from vbl.envs.noise import NoiseParams
from vbl.envs.shoot_pass import ShootPassParams
from vbl.params import param
from vbl.sysid.lag import identify
from vbl.sysid.params import CVAParams

__all__ = ["RowSetup", "TABLE1_ROWS", "OBJECT", "table1_scenarios", "table3_scenarios",
           "stats", "drop_per_seed", "identify_rows", "row_markdown", "claims_markdown",
           "swap_markdown",
           "identification_cells", "swap_test", "report"]

TABLE1_ROWS = ("goal", "ball", "random walk", "move to the ball")
OBJECT = {"goal": "goal", "ball": "ball", "random walk": "other", "move to the ball": "other"}
"""The identified object of each Table 1 row (its outputs: :func:`vbl.envs.collect.id_outputs`)."""


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


def table1_scenarios(c: CollectParams, r: RowSetup) -> dict[str, CollectParams]:
    """The four collection scenarios of Table 1 (keyed by row name) from the common setup
    ``c`` and the row changes ``r``."""
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
                     noise: NoiseParams) -> dict[tuple[str, str], CollectParams]:
    """Table 3's scenarios ``{(view, row): params}``: Table 1's ball, goal (shooter only)
    and move-to-ball ("other") rows with ``noise``, seen by the shooter and by the passer
    (``bodies``), plus the noise-free rows seen by the shooter."""
    t1 = table1_scenarios(c, r)
    out = {}
    for who in ("shooter", "passer"):
        noisy = {k: _observer(v.replace(noise=noise), bodies, who) for k, v in t1.items()}
        out[(who, "ball")] = noisy["ball"]
        if who == "shooter":
            out[(who, "goal")] = noisy["goal"]
        out[(who, "other")] = noisy["move to the ball"]
    for k in ("goal", "ball"):
        out[("noise-free", k)] = _observer(t1[k], bodies, "shooter")
    out[("noise-free", "other")] = _observer(t1["move to the ball"], bodies, "shooter")
    return out


def stats(res) -> dict:
    """Mean / population std over data sets of l, n, log det R, AIC of an identification
    (plus the modal l and n and the per-data-set values)."""
    out = {}
    for k, v in (("l", res.lag), ("n", res.n), ("logdet_R", res.logdet_R), ("aic", res.aic)):
        a = np.asarray(v, np.float64)
        out[k] = dict(mean=float(a.mean()), std=float(a.std()), per_seed=a.tolist())
    for k, v in (("l", res.lag), ("n", res.n)):
        out[k]["mode"] = int(np.bincount(np.asarray(v)).argmax())
    return out


def drop_per_seed(s: dict) -> dict:
    """:func:`stats` without the per-data-set values (for a run's summary)."""
    return {k: {q: v for q, v in d.items() if q != "per_seed"} for k, d in s.items()}


def identify_rows(data: dict, obj: dict, ident: CVAParams, y_unit: float) -> dict:
    """``{row: stats}``: identify every row's data sets (``data[row]``: CollectData with a
    leading data-set axis) with the outputs of object ``obj[row]`` in ``y_unit`` px."""
    return {row: stats(identify(np.asarray(d.u, np.float64), id_outputs(d, obj[row], y_unit),
                                ident)) for row, d in data.items()}


def row_markdown(cells: list[str], s: dict, paper: tuple | None, mode: bool = False) -> str:
    """One table row: the leading ``cells``, then l, n (with their modes if ``mode``),
    log det R, AIC as mean +- std over data sets, then the paper's l / n / log det R / AIC."""
    def ms(k, f):
        extra = f" (mode {s[k]['mode']})" if mode and "mode" in s[k] else ""
        return f"{s[k]['mean']:{f}} +- {s[k]['std']:{f}}{extra}"

    p = " / ".join(str(x) for x in paper) if paper else "-"
    return "| " + " | ".join([*cells, ms("l", ".2f"), ms("n", ".2f"), ms("logdet_R", ".3f"),
                             ms("aic", ".0f"), p]) + " |"


def claims_markdown(checks: dict[str, bool]) -> list[str]:
    """The lines of a ``| claim | holds |`` table (after a blank line)."""
    return ["", "| claim | holds |", "|---|---|"] + [
        f"| {c} | {'yes' if ok else '**no**'} |" for c, ok in checks.items()]


def identification_cells(s: dict, n: int) -> str:
    """``l / n / log det R / AIC`` of one row, each mean ± 95 % interval over ``n`` data
    sets."""
    return " / ".join(stat_cell(s[q], fmt=f, n=n) for q, f in (
        ("l", ".2f"), ("n", ".2f"), ("logdet_R", ".2f"), ("aic", ".0f")))


def _pred_logdet(model, u, y):
    """log det of the one-step prediction-error covariance of ``model`` on (u (N,m),
    y (N,q)), over t >= the model's history length (one data set; vmapped)."""
    h = model.history_length

    def body(hist, uy):
        ut, yt = uy
        e = yt - model.predict(hist, ut)
        return model.update_history(hist, ut, yt), e

    _, e = jax.lax.scan(body, model.init_history(), (u, y))
    e = e[h:]
    e = e - e.mean(0)
    cov = e.T @ e / e.shape[0]
    return jnp.linalg.slogdet(cov)[1]


_pred_batch = jax.jit(jax.vmap(_pred_logdet))


def swap_test(d_a: Any, d_b: Any, names: tuple[str, str], ident: CVAParams,
              y_unit: float) -> dict:
    """Ball models of two observers, own vs swapped: the data sets of each are split in
    halves (train / test, paired by seed); each observer's model, identified on its
    training half, predicts both observers' test halves. ``{"<a> data, <b> model": {mean,
    std}}`` of the log det of the one-step prediction-error covariance."""
    (a, b), half = names, d_a.u.shape[0] // 2
    if half < 1:
        raise ValueError("the swap test needs at least 2 seeds (train/test halves)")
    data = {}
    for who, d in ((a, d_a), (b, d_b)):
        u, y = np.asarray(d.u, np.float64), id_outputs(d, "ball", y_unit)
        model = identify(u[:half], y[:half], ident, model_dtype=jnp.float64).model
        data[who] = (model, (jnp.asarray(u[half:2 * half]), jnp.asarray(y[half:2 * half])))
    res = {f"{x} data, {m} model": _pred_batch(data[m][0], *data[x][1])
           for x, m in ((a, a), (a, b), (b, b), (b, a))}
    return {k: dict(mean=float(np.mean(v)), std=float(np.std(v))) for k, v in res.items()}


def swap_markdown(swap: dict) -> list[str]:
    """The lines of the model-swap table of :func:`swap_test`'s result."""
    lines = ["", "Model swap (ball; log det of the one-step prediction-error covariance on "
             "held-out data, mean +- std over seeds):", "", "| data | model | log det |",
             "|---|---|---|"]
    for k, v in swap.items():
        data, model = k.split(", ")
        lines.append(f"| {data} | {model} | {v['mean']:.3f} +- {v['std']:.3f} |")
    return lines


def report(res: RunResult) -> ReportSection:
    """The table the run wrote (its summary's ``markdown``)."""
    r = res.extra or res.summary.get("result", {})
    return ReportSection(markdown=r.get("markdown", "(no result)"))
