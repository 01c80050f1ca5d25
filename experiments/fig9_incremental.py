"""Figures 8 and 9: on-line incremental state-space segmentation (paper Section 2.2).

One robot per seed learns to shoot on the boxes of :mod:`vbl.spaces.incremental` with
:mod:`vbl.agents.segmentation_learner` while the ball shrinks twice (:mod:`vbl.envs.schedules`);
its final policy is compared with random primitives, the hand-written steering policy and
the grid baseline at equal experience. ``vbl run fig9_incremental [--quick] [--preset P]``.
"""

from __future__ import annotations

from flax import struct

from vbl.agents import segmentation_learner as sl
from vbl.engine import Experiment, register
from vbl.envs.schedules import BallChangeParams
from vbl.envs.shooting import ShootingParams
from vbl.params import param, section
from vbl.programs import segmentation_figures as figs
from vbl.programs.baselines import GridLearner, grid_agent, grid_train
from vbl.programs.segmentation_program import make_segmentation_program
from vbl.spaces.action_based import FeatureParams


@struct.dataclass
class Fig9Train:
    num_trials: int = param(1110, doc="trials recorded per learner (Figure 9's x axis)",
                            source="P", static=True, ge=1)
    num_chunks: int = param(20, doc="chunks per run", static=True, ge=1)
    updates_per_chunk: int = param(90, doc="structure updates per chunk (each after learner."
                                   "update_every primitives); chunks x this x update_every "
                                   "should exceed num_trials x env.max_steps", static=True, ge=1)
    eval_episodes: int = param(200, doc="evaluation episodes on fresh starts", static=True, ge=1)
    grid_baseline: bool = param(True, doc="final: also train and evaluate the grid baseline on "
                                "the final ball and the same starts", static=True)
    steer_reference: bool = param(True, doc="final: also evaluate the hand-written steering "
                                  "policy (train.steer_band) on the same starts", static=True)
    steer_band: float = param(20.0, doc="steering policy: FL / F / FR as the ball's image x2 is "
                              "left of -band / within / right of +band, else TL / TR towards "
                              "the side where the ball left the image", unit="px", gt=0.0)


def _grid() -> GridLearner:
    """vbl.programs.baselines' grid learner on Figure 9's env and final ball, 1 robot x 360
    chunks of 500 primitives: the on-line learner's experience (180,000 primitives per seed);
    evaluations at Figure 9's training start difficulty, one chunk each (the episodes last
    at most 150 primitives), on 128 rounds of the one robot's fresh starts."""
    return GridLearner(agent=grid_agent().replace(num_envs=1), train=grid_train().replace(
        eval_difficulty=0.1, num_chunks=360, eval_every=1, eval_chunks=1, eval_rounds=128))


@struct.dataclass
class Fig9Config:
    env: ShootingParams = section(lambda: ShootingParams(max_steps=150, start_difficulty=0.1),
                                  doc="shooting task (start difficulty 0.1, 150 primitives)")
    features: FeatureParams = section(FeatureParams, doc="feature normalisation")
    learner: sl.IncrementalParams = section(lambda: sl.IncrementalParams(
        update="monte_carlo", learning_rate=0.02, temperature=0.01), doc="segmentation + Monte "
        "Carlo values (docs/findings/fig9_incremental.md: 0.63 against 0.12 for q_learning)")
    change: BallChangeParams = section(BallChangeParams, doc="ball-size changes")
    train: Fig9Train = section(Fig9Train, doc="run length and evaluation")
    baseline: GridLearner = section(_grid, doc="grid baseline at equal experience")


Q_LEARNING = {"learner.update": "q_learning", "learner.learning_rate": 0.25,
              "learner.temperature": 0.02}
EARLIER = {**Q_LEARNING, "learner.value_split_gain": 0.0}          # model-error splits only
NO_CHANGE = {"change.change_trial_1": 100000, "change.change_trial_2": 100000}
EXPERIMENT = register(Experiment(
    name="fig9_incremental",
    description="Figs 8-9: on-line incremental state segmentation, ball size changed twice",
    default_config=Fig9Config(),
    make_program=make_segmentation_program,
    # --quick: a smoke run (120 trials are too few to learn much; the windows shrink to fit)
    quick={"train.num_trials": 120, "change.change_trial_1": 40, "change.change_trial_2": 80,
           "train.num_chunks": 3, "train.updates_per_chunk": 60, "train.eval_episodes": 64,
           "train.grid_baseline": False, "train.steer_reference": False},
    # the variants docs/findings/fig9_incremental.md reports
    presets={"q_learning": Q_LEARNING, "q_learning_model_splits": EARLIER,
             "q_learning_no_change": {**EARLIER, **NO_CHANGE, "train.num_trials": 800},
             "q_learning_small_ball": {**Q_LEARNING, **NO_CHANGE, "change.radius_0": 0.1,
                                       "train.num_trials": 500, "train.num_chunks": 8,
                                       "train.grid_baseline": False, "train.eval_episodes": 100},
             "no_baselines": {"train.grid_baseline": False, "train.steer_reference": False},
             "grid_full_budget": {"baseline.agent.num_envs": 64,
                                  "baseline.train.num_chunks": 100}},
    seeds=8, quick_seeds=8, paper_result=True,
    paper={"trials": 1110, "ball size change": "twice, around trial 500"},
    report=figs.report, paper_rows=figs.paper_rows,
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
