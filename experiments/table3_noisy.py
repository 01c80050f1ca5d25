"""Table 3 in simulation: identification with the Section 3.4.2 noise model on, as seen from
the shooter and from the passer, and the model-swap test.

The shooter and the passer have different bodies (``ShootPassParams``: the passer's camera
is tilted 6 deg less, its motor is 25 % slower and its steering limit 8 deg smaller; why
these amounts: ``docs/two_robot_task.md``, Bodies).
Each observer collects data as in Table 1 while the other robot moves to the ball, with
image noise, ball-centroid eccentricity and tire slip on (``vbl.envs.noise.NOISE_ON``); the
same scenarios without noise from the shooter are the reference
(:func:`vbl.programs.identification.table3_scenarios`). Each learner (one seed) collects one
data set per row and identifies it in its program (:mod:`vbl.programs.identification`).
Model swap: each learner also collects a held-out ball data set per observer; each
observer's ball model (identified on its row's data set) predicts both held-out sets.

Preset ``pixels`` (the paper's real pipeline): every row's features come from the rendered
camera image through the colour-blob detector (``collect.obs_source="pixels"``,
:mod:`vbl.envs.pixels`), and the noisy rows' image noise is noise in the image
(``noise.pixel_std``, :data:`vbl.envs.noise.NOISE_ON_PIXELS`) instead of noise on the
features; the noise-free rows are then pixel processing alone.

Run: ``vbl run table3_noisy [--quick] [--preset pixels]`` or
``python experiments/table3_noisy.py``.
"""

from __future__ import annotations

import numpy as np
from flax import struct

from vbl.engine import Experiment, RunResult, register
from vbl.engine.experiment import PaperRow
from vbl.engine.report import claim, seeds_cell
from vbl.envs.collect import CollectParams
from vbl.envs.noise import NOISE_ON, NOISE_ON_PIXELS, NoiseParams
from vbl.envs.shoot_pass import ShootPassParams
from vbl.params import param, section
from vbl.programs.identification import (
    RowSetup,
    check_scenarios,
    claims_markdown,
    identification_cells,
    identification_program,
    point_report,
    row_markdown,
    row_stats,
    swap_markdown,
    table3_scenarios,
)
from vbl.programs.paper import TABLE3
from vbl.sysid.params import CVAParams

ROWS = {"shooter_ball": ("from the shooter", "ball"), "shooter_goal": ("from the shooter", "goal"),
        "shooter_other": ("from the shooter", "passer"),
        "passer_ball": ("from the passer", "ball"), "passer_other": ("from the passer", "shooter"),
        "noise_free_goal": ("noise-free (shooter)", "goal"),
        "noise_free_ball": ("noise-free (shooter)", "ball"),
        "noise_free_other": ("noise-free (shooter)", "move-to-ball robot")}
OBJECTS = {k: k.rsplit("_", 1)[1] for k in ROWS}
SWAP = {"shooter": ("shooter_ball", "shooter_ball_test"),
        "passer": ("passer_ball", "passer_ball_test")}


@struct.dataclass
class Table3Config:
    collect: CollectParams = section(lambda: CollectParams(num_steps=500),
                                     doc="common data-collection setup (Table 1's)")
    rows: RowSetup = section(RowSetup, doc="per-row collection changes (Table 1's)")
    bodies: ShootPassParams = section(ShootPassParams, doc="the two robots (cameras, "
                                      "passer_body); world.four_wheel is the shooter's body")
    noise: NoiseParams = section(lambda: NOISE_ON, doc="noise model (on)")
    ident: CVAParams = section(lambda: CVAParams(standardize=False, lag_max=6, lag_rule="paper"),
                               doc="CVA/AIC/lag rule (as Table 1)")
    y_unit: float = param(4.0, doc="unit of the identification outputs", unit="px", gt=0.0)

    def check(self) -> None:
        check_scenarios(scenarios(self), OBJECTS, self.ident)


def scenarios(c: Table3Config) -> dict[str, CollectParams]:
    """The rows, then each observer's held-out ball data set (its row's scenario again)."""
    sc = table3_scenarios(c.collect, c.rows, c.bodies, c.noise)
    return sc | {test: sc[train] for train, test in SWAP.values()}


def make_program(cfg: Table3Config):
    return identification_program(cfg, scenarios, OBJECTS, SWAP)


def checks(f: dict, i: int) -> dict[str, str]:
    """The paper's claims at sweep point ``i``, each a verdict on the 95 % interval of a
    difference over seeds (:func:`vbl.engine.report.claim`; the swap paired per seed)."""
    def lag(key):
        return np.asarray(f[f"l_{key}"][i], np.float64)

    def grows(obj):
        free = lag(f"noise_free_{obj}")
        return "; ".join(f"{view}: {claim(lag(view + '_' + obj), free, fmt='.2f')}"
                         for view in ("shooter", "passer"))

    def swap(data, model):
        return np.asarray(f[f"swap_{data}_data_{model}_model"][i], np.float64)

    return {"l grows for the ball vs noise-free": grows("ball"),
            "l grows for the other robot vs noise-free": grows("other"),
            "swapping the ball models raises the prediction error (log det, swapped − own)":
                "; ".join(f"{d}'s data: {claim(swap(d, o), swap(d, d), paired=True, fmt='.2f')}"
                          for d, o in (("shooter", "passer"), ("passer", "shooter")))}


def _source(cfg: Table3Config) -> str:
    """How the features are made, and the image noise, for the table's title."""
    if cfg.collect.obs_source == "pixels":
        rp = cfg.collect.pixels.render
        return (f"features from {rp.width} x {rp.height} px images through the colour-blob "
                f"detector; noise model on: pixel noise {cfg.noise.pixel_std:g} of full scale")
    return f"analytic features; noise model on: image {cfg.noise.image_std:g} px"


def table(res: RunResult, i: int) -> str:
    cfg, f = res.config, res.final
    t = {k: row_stats(f, i, k) for k in ROWS}
    lines = [f"Table 3 (simulation, {_source(cfg)}, centroid "
             f"eccentricity {cfg.noise.ecc_centroid:g}, rolling wobble "
             f"{cfg.noise.ecc_turn_std:g} rad, tire slip {cfg.noise.slip_std:g}); mean +- std "
             f"over {res.seeds} seeds (one data set of N = {cfg.collect.num_steps} per row and "
             f"seed), outputs in {cfg.y_unit:g} px units", "",
             "| view | object | l (ours) | n (ours) | log det R (ours) | AIC (ours) | "
             "l / n / log det R / AIC (paper, real robots) |", "|---|---|---|---|---|---|---|"]
    for key, (view, obj) in ROWS.items():
        lines.append(row_markdown([view, obj], t[key], TABLE3.get(view, {}).get(obj)))
    lines += swap_markdown(f, i, tuple(SWAP)) + claims_markdown(checks(f, i))
    return "\n".join(lines)


def paper_rows(res: RunResult) -> list[PaperRow]:
    rows = []
    for i, pt in enumerate(res.points):
        at = f" ({', '.join(f'{p}={v}' for p, v in pt.items())})" if pt else ""
        rows += [PaperRow(f"Table 3, {view}, {obj}: l / n / log det R / AIC{at}",
                          " / ".join(str(x) for x in TABLE3[view][obj]),
                          identification_cells(res.final, i, key))
                 for key, (view, obj) in ROWS.items() if view in TABLE3]
        for data, other in (("shooter", "passer"), ("passer", "shooter")):
            own, swapped = (res.final[f"swap_{data}_data_{m}_model"][i] for m in (data, other))
            rows.append(PaperRow(
                f"Table 3, {data}'s ball data: log det, own / {other}'s model{at}",
                "swapped: large errors (no number)",
                f"{seeds_cell(own, fmt='.2f')} / {seeds_cell(swapped, fmt='.2f')}"))
    return rows


EXPERIMENT = register(Experiment(
    name="table3_noisy",
    description="Table 3 in simulation: identification with image noise, ball eccentricity "
                "and tire slip, from the shooter and the passer, and the model-swap test",
    default_config=Table3Config(),
    make_program=make_program, seeds=64, quick_seeds=16,
    cost=190.0,  # CPU-s of a cold --quick run (compile-dominated)
    paper_result=True, paper={"table3": TABLE3}, report=point_report(table),
    paper_rows=paper_rows,
    headline=("l_shooter_ball", "l_passer_ball", "l_shooter_other", "l_noise_free_ball"),
    presets={"pixels": {"collect.obs_source": "pixels",
                        "noise.image_std": NOISE_ON_PIXELS.image_std,
                        "noise.pixel_std": NOISE_ON_PIXELS.pixel_std}},
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
