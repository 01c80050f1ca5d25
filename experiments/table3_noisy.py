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

from flax import struct

from vbl.engine import Experiment, register
from vbl.envs.collect import CollectParams
from vbl.envs.noise import NOISE_ON, NOISE_ON_PIXELS, NoiseParams
from vbl.envs.shoot_pass import ShootPassParams
from vbl.params import param, section
from vbl.programs.identification import (
    RowSetup,
    check_scenarios,
    identification_program,
    point_report,
    table3_scenarios,
)
from vbl.programs.paper import TABLE3
from vbl.programs.table3_report import OBJECTS, SWAP, paper_rows, table
from vbl.sysid.params import CVAParams


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


EXPERIMENT = register(Experiment(
    name="table3_noisy",
    description="Table 3 in simulation: identification with image noise, ball eccentricity "
                "and tire slip, from the shooter and the passer, and the model-swap test",
    default_config=Table3Config(),
    make_program=make_program, seeds=64, quick_seeds=16,
    paper_result=True, paper={"table3": TABLE3}, report=point_report(table),
    paper_rows=paper_rows,
    headline=("l_shooter_ball", "l_passer_ball", "l_shooter_other", "l_noise_free_ball"),
    presets={"pixels": {"collect.obs_source": "pixels",
                        "noise.image_std": NOISE_ON_PIXELS.image_std,
                        "noise.pixel_std": NOISE_ON_PIXELS.pixel_std}},
    published_presets=("pixels",),
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
