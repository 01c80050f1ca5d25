"""brax PPO as a deep-RL comparator of the tabular learners (issue: which state does a
learner need when other agents move?).

Two experiments, each a vmapped PPO program (:mod:`vbl.programs.ppo_program`) with the
categorical policy of :mod:`vbl.agents.ppo`:

* ``ppo_comparator``: the two-robot task of Table 2 (shooter and passer) with three inputs,
  current features, the last 3 frames, and the CVA state vector of the tabular learner
  (its own identification per seed), without a curriculum (as the tabular learner), at
  Table 2's experience (2.56 M primitives); beside the tabular results of Table 2 (the
  ``table2_shoot_pass`` run of the same ``vbl reproduce``) and the paper.
* ``ppo_shooting``: the shooting task of Section 2 (100 s limit, fully random starts), with
  and without the curriculum (LEM for PPO), at the grid baseline's experience (~3 M
  primitives); beside the grid baseline (the ``grid_shooting`` run of the same
  ``vbl reproduce``).

Reports: :mod:`vbl.programs.ppo_report`. Run: ``vbl run ppo_comparator`` / ``vbl run
ppo_shooting``, or ``--quick``.
"""

from __future__ import annotations

from functools import partial

from flax import struct

from vbl.agents.cva_state import CVAStateParams
from vbl.agents.ppo_params import PPOParams
from vbl.engine import Experiment, register
from vbl.envs.shoot_pass import ShootPassParams
from vbl.envs.shooting import ShootingParams
from vbl.params import section
from vbl.programs.paper import TABLE2
from vbl.programs.ppo_program import (
    InputChoice,
    PPORunParams,
    make_shoot_pass_program,
    make_shooting_program,
)
from vbl.programs.ppo_report import (
    shoot_pass_rows,
    shoot_pass_section,
    shooting_rows,
    shooting_section,
)
from vbl.programs.table2 import table2_cva

QUICK_PPO = {"ppo.num_envs": 16, "ppo.batch_size": 16, "ppo.num_minibatches": 2,
             "ppo.steps_per_chunk": 2, "ppo.eval_envs": 8, "run.final_eval_envs": 16,
             "run.num_chunks": 2}


@struct.dataclass
class ShootPassConfig:
    env: ShootPassParams = section(ShootPassParams, doc="the two-robot task (Table 2's)")
    inputs: InputChoice = section(InputChoice, doc="what PPO sees")
    cva: CVAStateParams = section(table2_cva, doc="the tabular learner's CVA "
                                  "pipeline (collection, identification; its quantiser is "
                                  "unused)")
    ppo: PPOParams = section(PPOParams, doc="brax PPO")
    run: PPORunParams = section(PPORunParams, doc="50 chunks x 51,200 = 2.56 M primitives")


@struct.dataclass
class ShootingConfig:
    env: ShootingParams = section(lambda: ShootingParams(max_steps=1000),
                                  doc="shooting, 100 s limit (the grid baseline's)")
    ppo: PPOParams = section(PPOParams, doc="brax PPO")
    run: PPORunParams = section(lambda: PPORunParams(num_chunks=60),
                                doc="60 chunks x 51,200 = 3.07 M primitives")


EXPERIMENT = register(Experiment(
    name="ppo_comparator",
    description="brax PPO on the two-robot task: current features vs frame stack vs CVA state",
    default_config=ShootPassConfig(), make_program=make_shoot_pass_program,
    quick={**QUICK_PPO, "cva.collect_steps": 1000},
    # --quick trains 2 chunks: a smoke test of the program, no result (full reproduce only)
    seeds=8, quick_seeds=2, paper_result=True, in_quick_reproduce=False, paper=TABLE2,
    percent=True,
    report=partial(shoot_pass_section, paper=TABLE2), paper_rows=shoot_pass_rows,
    sweep={"env.task_pass": [False, True], "inputs.index": [0, 1, 2]},
    report_reads=("table2_shoot_pass",),  # the tabular learner's column
))

SHOOTING = register(Experiment(
    name="ppo_shooting",
    description="brax PPO on the shooting task, with and without the curriculum",
    default_config=ShootingConfig(), make_program=make_shooting_program,
    quick=QUICK_PPO,
    seeds=8, quick_seeds=2, paper_result=True, in_quick_reproduce=False, percent=True,
    report=shooting_section,
    paper_rows=shooting_rows,
    sweep={"ppo.curriculum.enabled": [False, True]},
    report_reads=("grid_shooting",),  # the grid baseline's rows
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
