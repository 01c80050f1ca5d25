"""Engine programs of brax PPO on vbl's tasks (the ``ppo_comparator`` and ``ppo_shooting``
experiments; their report tables and figures: :mod:`vbl.programs.ppo_report`).

* :func:`make_shooting_program`: the shooting task of Section 2 (9 features, 9 primitives)
  through :class:`vbl.envs.brax_adapter.BraxAdapter`, with or without the curriculum
  (``ppo.curriculum.enabled``, traced).
* :func:`make_shoot_pass_program`: the two-robot task (``ShootPassEnv("select")``: the
  traced ``env.task_pass`` picks shooter or passer) through
  :class:`vbl.agents.ppo_inputs.InputEnv` (kind "select": the traced ``inputs.index`` picks
  current features, a frame stack or the CVA state; one compilation for all six rows),
  with or without the curriculum on ``ShootPassParams.start_difficulty``.

Per chunk (per learner): ``env_steps`` (training env steps at the end of the chunk),
``success_rate`` (deterministic policy, ``ppo.eval_envs`` fresh starts at the task's start
distribution, first episode each), ``level_success_rate`` (same at the curriculum's
difficulty), ``difficulty``, ``episodes``, ``train_success_rate``, ``loss``, ``entropy``.
``final``: ``greedy_success_rate`` on ``run.final_eval_envs`` fresh starts.
"""

from __future__ import annotations

from typing import Any

import jax
from flax import struct

from vbl.agents.ppo_inputs import InputEnv, InputParams, prepare_models
from vbl.engine.experiment import Program
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv
from vbl.params import param

__all__ = ["PPORunParams", "InputChoice", "make_shooting_program", "make_shoot_pass_program"]


@struct.dataclass
class PPORunParams:
    """Run length and the final evaluation."""

    num_chunks: int = param(50, doc="engine chunks per run (each ppo.env_steps_per_chunk "
                            "env steps per learner)", static=True, ge=1)
    final_eval_envs: int = param(256, doc="fresh starts of the final deterministic-policy "
                                 "evaluation (first episode each)", static=True, ge=1)


@struct.dataclass
class InputChoice:
    """What the two-robot PPO learner sees."""

    index: int = param(0, doc="input: 0 current features (26,), 1 the last `frames` "
                       "observations stacked, 2 the tabular learner's CVA state vector "
                       "(traced; all three zero-padded to one length)", ge=0, le=2)
    frames: int = param(3, doc="observations stacked for input 1 (3 = the CVA filter's "
                        "longest history, cva.ident.lag_max)", static=True, ge=1)


def _program(lrn, init_env, num_chunks: int, final_envs: int):
    def init(key, c):
        k_env, k_lrn = jax.random.split(key)
        return lrn.init(k_lrn, init_env(k_env, c), c.ppo)

    def step(carry, c):
        return lrn.train_chunk(carry, c.ppo)

    def final(carry, c, key):
        return {"greedy_success_rate": lrn.evaluate(carry, key, 1.0, final_envs)}

    return Program(init=init, step=step, num_chunks=num_chunks, final=final,
                   progress_metric="success_rate")


def make_shooting_program(cfg: Any):
    """Program for a config with sections ``env`` (ShootingParams), ``ppo`` (PPOParams),
    ``run`` (PPORunParams); evaluation at start difficulty 1 (fully random starts)."""
    from vbl.agents.ppo_train import make_ppo_learner  # brax: imported when a program is built
    from vbl.envs.brax_adapter import BraxAdapter

    env = ShootingEnv()

    def make_env(env_params, difficulty):
        return BraxAdapter(env, env_params.replace(start_difficulty=difficulty))

    lrn = make_ppo_learner(make_env, env.observation_shape[0], env.num_actions, cfg.ppo)
    return _program(lrn, lambda key, c: c.env, cfg.run.num_chunks, cfg.run.final_eval_envs)


def make_shoot_pass_program(cfg: Any):
    """Program for a config with sections ``env`` (ShootPassParams), ``inputs``
    (InputChoice), ``cva`` (CVAStateParams of the tabular learner), ``ppo``, ``run``."""
    from vbl.agents.ppo_train import make_ppo_learner  # brax: imported when a program is built
    from vbl.envs.brax_adapter import BraxAdapter, with_difficulty

    base = ShootPassEnv("select")
    ienv = InputEnv(base, "select", cfg.inputs.frames, cfg.cva, m=2)

    def make_env(env_params, difficulty):
        return BraxAdapter(ienv, with_difficulty(env_params, difficulty))

    def init_env(key, c):
        models = prepare_models(base, key, c.cva, c.env)
        return InputParams(c.env, models, c.inputs.index)

    lrn = make_ppo_learner(make_env, ienv.observation_shape[0], ienv.num_actions, cfg.ppo)
    return _program(lrn, init_env, cfg.run.num_chunks, cfg.run.final_eval_envs)
