"""Table 3 in simulation: identification with the Section 3.4.2 noise model on, as seen from
the shooter and from the passer, and the model-swap test.

The shooter and the passer have different bodies (``ShootPassParams``: the passer's
camera is tilted -20 deg instead of -26 deg, its motor is slower and its steering angle
smaller). Each observer collects data with random view-keeping actions (as in Table 1)
while the other robot moves to the ball (the passer's / shooter's own approach), with
image noise, ball-centroid eccentricity and tire slip on (``vbl.envs.noise.NOISE_ON``).
The same scenarios are collected with the noise off from the shooter (the noise-free
reference, as Table 1), all in one compiled computation.

Model swap: the data sets of each observer are split in halves (train / test, paired by
seed). The ball model identified on the shooter's training data predicts the shooter's
test data (own model) and the passer's test data (swapped), and vice versa; the table
reports log det of the one-step prediction-error covariance (y in ``y_unit`` px).

Run: ``vbl run table3_noisy [--quick]`` or ``python experiments/table3_noisy.py``.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.engine import Experiment, RunContext, RunResult, register
from vbl.engine.experiment import PaperRow
from vbl.engine.registry import load_script
from vbl.engine.report import stat_cell
from vbl.envs.collect import CollectParams, collect_many, id_outputs
from vbl.envs.noise import NOISE_ON, NoiseParams
from vbl.envs.shoot_pass import ShootPassParams
from vbl.params import param, section
from vbl.sysid.lag import identify
from vbl.sysid.params import CVAParams

T1 = load_script(Path(__file__).with_name("table1_identification.py"))  # shared helpers

PAPER = {"from the shooter": {"ball": (4, 4, 1.88, 284), "goal": (1, 3, -1.73, -817),
                              "passer": (5, 4, 3.43, 329)},
         "from the passer": {"ball": (4, 4, 1.36, 173), "shooter": (5, 4, 2.17, 284)}}


@struct.dataclass
class Table3Config:
    collect: CollectParams = section(lambda: CollectParams(num_steps=500),
                                     doc="common data-collection setup (Table 1's)")
    rows: T1.RowSetup = section(T1.RowSetup, doc="per-row collection changes (Table 1's)")
    bodies: ShootPassParams = section(ShootPassParams, doc="the two robots (cameras, "
                                      "passer_body); world.four_wheel is the shooter's body")
    noise: NoiseParams = section(lambda: NOISE_ON, doc="noise model (on)")
    ident: CVAParams = section(lambda: CVAParams(standardize=False, lag_max=6, lag_rule="paper"),
                               doc="CVA/AIC/lag rule (as Table 1)")
    y_unit: float = param(4.0, doc="unit of the identification outputs", unit="px", gt=0.0)


def _observer(base: CollectParams, cfg: Table3Config, who: str) -> CollectParams:
    b = cfg.bodies
    if who == "shooter":
        return base.replace(camera=b.shooter_camera)
    return base.replace(camera=b.passer_camera,
                        world=base.world.replace(four_wheel=b.passer_body))


def scenarios(cfg: Table3Config) -> dict[tuple[str, str], CollectParams]:
    """{(view, row): params}: noisy rows from the shooter and the passer, plus noise-free
    rows from the shooter."""
    t1 = T1.scenarios(cfg)  # uses cfg.collect and cfg.rows
    out = {}
    for who in ("shooter", "passer"):
        noisy = {k: _observer(v.replace(noise=cfg.noise), cfg, who) for k, v in t1.items()}
        out[(who, "ball")] = noisy["ball"]
        if who == "shooter":
            out[(who, "goal")] = noisy["goal"]
        out[(who, "other")] = noisy["move to the ball"]
    for k in ("goal", "ball"):
        out[("noise-free", k)] = _observer(t1[k], cfg, "shooter")
    out[("noise-free", "other")] = _observer(t1["move to the ball"], cfg, "shooter")
    return out


OBJ = {"ball": "ball", "goal": "goal", "other": "other"}


def _pred_logdet(model, u, y):
    """log det of the one-step prediction-error covariance of ``model`` on (u (N,m), y (N,q)),
    over t >= lag_max (one data set; vmapped)."""
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


def swap_test(d_s, d_p, cfg: Table3Config) -> dict:
    """Ball models: own vs swapped one-step prediction error (train/test halves)."""
    ys = id_outputs(d_s, "ball", cfg.y_unit)
    yp = id_outputs(d_p, "ball", cfg.y_unit)
    us, up = np.asarray(d_s.u, np.float64), np.asarray(d_p.u, np.float64)
    half = us.shape[0] // 2
    if half < 1:
        raise ValueError("the swap test needs at least 2 seeds (train/test halves)")
    m_s = identify(us[:half], ys[:half], cfg.ident, model_dtype=jnp.float64).model
    m_p = identify(up[:half], yp[:half], cfg.ident, model_dtype=jnp.float64).model
    ts = (jnp.asarray(us[half:2 * half]), jnp.asarray(ys[half:2 * half]))
    tp = (jnp.asarray(up[half:2 * half]), jnp.asarray(yp[half:2 * half]))
    res = {"shooter data, shooter model": _pred_batch(m_s, *ts),
           "shooter data, passer model": _pred_batch(m_p, *ts),
           "passer data, passer model": _pred_batch(m_p, *tp),
           "passer data, shooter model": _pred_batch(m_s, *tp)}
    return {k: dict(mean=float(np.mean(v)), std=float(np.std(v))) for k, v in res.items()}


def checks(t: dict, swap: dict) -> dict:
    ld = swap
    return {
        "l grows for the ball vs noise-free": bool(
            t[("shooter", "ball")]["l"]["mean"] > t[("noise-free", "ball")]["l"]["mean"]
            and t[("passer", "ball")]["l"]["mean"] > t[("noise-free", "ball")]["l"]["mean"]),
        "l grows for the other robot vs noise-free": bool(
            t[("shooter", "other")]["l"]["mean"] > t[("noise-free", "other")]["l"]["mean"]
            and t[("passer", "other")]["l"]["mean"] > t[("noise-free", "other")]["l"]["mean"]),
        "swapping the ball models raises both prediction errors": bool(
            ld["shooter data, passer model"]["mean"] > ld["shooter data, shooter model"]["mean"]
            and ld["passer data, shooter model"]["mean"]
            > ld["passer data, passer model"]["mean"]),
    }


NAMES = {("shooter", "ball"): ("from the shooter", "ball"),
         ("shooter", "goal"): ("from the shooter", "goal"),
         ("shooter", "other"): ("from the shooter", "passer"),
         ("passer", "ball"): ("from the passer", "ball"),
         ("passer", "other"): ("from the passer", "shooter")}


def markdown(t: dict, swap: dict, seeds: int, cfg: Table3Config) -> str:
    lines = [f"Table 3 (simulation, noise model on: image {cfg.noise.image_std:g} px, centroid "
             f"eccentricity {cfg.noise.ecc_centroid:g}, rolling wobble "
             f"{cfg.noise.ecc_turn_std:g} rad, tire slip {cfg.noise.slip_std:g}); mean +- std "
             f"over {seeds} data sets of N = {cfg.collect.num_steps}, outputs in "
             f"{cfg.y_unit:g} px units", "",
             "| view | object | l (ours) | n (ours) | log det R (ours) | AIC (ours) | "
             "l / n / log det R / AIC (paper, real robots) |", "|---|---|---|---|---|---|---|"]

    def row(view, obj, s, paper):
        p = " / ".join(str(x) for x in paper) if paper else "-"
        return (f"| {view} | {obj} | {s['l']['mean']:.2f} +- {s['l']['std']:.2f} | "
                f"{s['n']['mean']:.2f} +- {s['n']['std']:.2f} | {s['logdet_R']['mean']:.3f} +- "
                f"{s['logdet_R']['std']:.3f} | {s['aic']['mean']:.0f} +- {s['aic']['std']:.0f} "
                f"| {p} |")

    for key, (view, obj) in NAMES.items():
        lines.append(row(view, obj, t[key], PAPER[view][obj]))
    for k, obj in (("goal", "goal"), ("ball", "ball"), ("other", "move-to-ball robot")):
        lines.append(row("noise-free (shooter)", obj, t[("noise-free", k)], None))
    lines += ["", "Model swap (ball; log det of the one-step prediction-error covariance on "
              "held-out data, mean +- std over seeds):", "", "| data | model | log det |",
              "|---|---|---|"]
    for k, v in swap.items():
        data, model = k.split(", ")
        lines.append(f"| {data} | {model} | {v['mean']:.3f} +- {v['std']:.3f} |")
    lines += ["", "| claim | holds |", "|---|---|"]
    lines += [f"| {c} | {'yes' if ok else '**no**'} |" for c, ok in checks(t, swap).items()]
    return "\n".join(lines) + "\n"


def run(ctx: RunContext) -> dict:
    cfg: Table3Config = ctx.config
    sc = scenarios(cfg)
    datas = dict(zip(sc, collect_many(jax.random.PRNGKey(ctx.base_seed), list(sc.values()),
                                      ctx.seeds), strict=True))
    t = {}
    for key, d in datas.items():
        y = id_outputs(d, OBJ[key[1]], cfg.y_unit)
        t[key] = T1.stats(identify(np.asarray(d.u, np.float64), y, cfg.ident))
    swap = swap_test(datas[("shooter", "ball")], datas[("passer", "ball")], cfg)
    md = markdown(t, swap, ctx.seeds, cfg)
    (ctx.out_dir / "table3.md").write_text(md)
    if not ctx.quiet:
        print(md)
    for s in t.values():
        for v in s.values():
            v.pop("per_seed", None)
    return {"tables": {f"{a}/{b}": s for (a, b), s in t.items()}, "swap": swap,
            "checks": checks(t, swap), "markdown": md}


def paper_rows(res: RunResult) -> list[PaperRow]:
    r = res.extra or res.summary.get("result", {})
    t, swap = r["tables"], r["swap"]
    rows = [PaperRow(f"Table 3, {view}, {obj}: l / n / log det R / AIC",
                     " / ".join(str(x) for x in PAPER[view][obj]),
                     T1.identification_cells(t[f"{a}/{b}"], res.seeds))
            for (a, b), (view, obj) in NAMES.items()]
    half = res.seeds // 2  # the swap test predicts the held-out half of the data sets
    for data, other in (("shooter", "passer"), ("passer", "shooter")):
        own, swapped = swap[f"{data} data, {data} model"], swap[f"{data} data, {other} model"]
        rows.append(PaperRow(f"Table 3, {data}'s ball data: log det, own / {other}'s model",
                             "swapped: large errors (no number)",
                             f"{stat_cell(own, fmt='.2f', n=half)} / "
                             f"{stat_cell(swapped, fmt='.2f', n=half)}"))
    return rows


EXPERIMENT = register(Experiment(
    name="table3_noisy",
    description="Table 3 in simulation: identification with image noise, ball eccentricity "
                "and tire slip, from the shooter and the passer, and the model-swap test",
    default_config=Table3Config(),
    run=run,
    quick={},
    seeds=64,
    quick_seeds=16,
    cost=70.0,  # s of a cold --quick run on 2 cores (compile-dominated)
    group="identification",  # Tables 1 and 3 share the collection and CVA programs
    paper_result=True,
    paper={"table3": PAPER},
    report=T1.report,
    paper_rows=paper_rows,
    # parameters added after run folders were written: the values of the code before them
    legacy_values={"bodies.start_difficulty": 1.0},
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
