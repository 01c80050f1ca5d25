"""vbl.programs: the paper's learners as engine programs (one tabular learner for every
state map the paper compares: the grid, current features, CVA state vectors; action-based
and incremental state spaces, system identification, the PPO comparator), with their
reports and figures. Each ``make_*_program`` returns a :class:`vbl.engine.Program`
that the engine vmaps over seeds and sweep values (docs/engine.md)."""
