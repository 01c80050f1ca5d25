"""vbl.agents: batched tabular Q-learning, exploration, Learning from Easy Missions."""

from vbl.agents.exploration import (
    ExplorationParams,
    ScheduleParams,
    schedule_value,
    select_action,
)
from vbl.agents.lem import LEMParams, LEMState, lem_init, lem_update
from vbl.agents.qlearning import (
    QLearningRunner,
    QRunnerParams,
    QRunnerState,
    init_q,
    learner_keys,
    make_qlearning_runner,
    q_update,
    stack_for_learners,
)
from vbl.agents.traces import TraceParams, TraceState, trace_init, trace_update

__all__ = [
    "ExplorationParams",
    "ScheduleParams",
    "schedule_value",
    "select_action",
    "LEMParams",
    "LEMState",
    "lem_init",
    "lem_update",
    "QLearningRunner",
    "QRunnerParams",
    "QRunnerState",
    "init_q",
    "learner_keys",
    "make_qlearning_runner",
    "q_update",
    "stack_for_learners",
    "TraceParams",
    "TraceState",
    "trace_init",
    "trace_update",
]
