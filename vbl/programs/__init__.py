"""vbl.programs: the paper's learners as engine programs (Q-learning on the grid, action-based
and incremental state spaces, CVA state vectors, system identification, the PPO comparator),
with their reports and figures. Each ``make_*_program`` returns a :class:`vbl.engine.Program`
that the engine vmaps over seeds and sweep values (docs/engine.md)."""
