"""Table 3's report: the identification table per sweep point beside the paper's real-robot
numbers, the model-swap test and the paper's claims as verdicts; the rows beside the paper
for ``vbl reproduce``'s headline table. The rows (:data:`ROWS`) name the data sets of
:func:`vbl.programs.identification.table3_scenarios`."""

from __future__ import annotations

import numpy as np

from vbl.engine.experiment import PaperRow, RunResult
from vbl.engine.report import claim, seeds_cell
from vbl.programs.identification import (
    claims_markdown,
    identification_cells,
    row_markdown,
    row_stats,
    swap_markdown,
)
from vbl.programs.paper import TABLE3

__all__ = ["ROWS", "OBJECTS", "SWAP", "checks", "table", "paper_rows"]

ROWS = {"shooter_ball": ("from the shooter", "ball"), "shooter_goal": ("from the shooter", "goal"),
        "shooter_other": ("from the shooter", "passer"),
        "passer_ball": ("from the passer", "ball"), "passer_other": ("from the passer", "shooter"),
        "noise_free_goal": ("noise-free (shooter)", "goal"),
        "noise_free_ball": ("noise-free (shooter)", "ball"),
        "noise_free_other": ("noise-free (shooter)", "move-to-ball robot")}
OBJECTS = {k: k.rsplit("_", 1)[1] for k in ROWS}
SWAP = {"shooter": ("shooter_ball", "shooter_ball_test"),
        "passer": ("passer_ball", "passer_ball_test")}


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


def _source(cfg) -> str:
    """How the features are made, and the image noise, for the title of the table of
    ``cfg`` (the experiment's config)."""
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
             f"{cfg.noise.ecc_turn_std:g} rad, tire slip {cfg.noise.slip_std:g}); mean ± 95 % "
             f"interval over {res.seeds} seeds (one data set of N = {cfg.collect.num_steps} per "
             f"row and seed), outputs in {cfg.y_unit:g} px units", "",
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
