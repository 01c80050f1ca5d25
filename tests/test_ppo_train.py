"""The PPO learner's curriculum rule and parameter checks (the learner itself runs in the
ppo_comparator experiment and benchmarks/ppo_throughput.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.agents.ppo_params import CurriculumParams, PPONetParams, PPOParams
from vbl.agents.ppo_train import curriculum_update, make_ppo_learner
from vbl.params import ParamError, validate


def test_curriculum_rises_by_step_when_success_reaches_the_level():
    cur = CurriculumParams(enabled=True, step=0.1, success_level=0.8)
    d = jnp.asarray([0.0, 0.0, 0.5, 0.95, 1.0])
    sr = jnp.asarray([0.8, 0.79, 1.0, 0.9, 1.0])
    np.testing.assert_allclose(curriculum_update(cur, d, sr, 1.0), [0.1, 0.0, 0.6, 1.0, 1.0],
                               rtol=1e-6)
    off = cur.replace(enabled=False)
    np.testing.assert_array_equal(curriculum_update(off, d, sr, 1.0), d)


def test_curriculum_climbs_to_the_task_in_ceil_steps():
    """Always successful: 0 -> task difficulty 0.7 in ceil(0.7 / 0.25) = 3 updates."""
    cur = CurriculumParams(enabled=True, step=0.25, success_level=0.5)
    d = jnp.float32(0.0)
    seen = []
    for _ in range(5):
        d = curriculum_update(cur, d, jnp.float32(1.0), jnp.float32(0.7))
        seen.append(float(d))
    np.testing.assert_allclose(seen, [0.25, 0.5, 0.7, 0.7, 0.7], rtol=1e-6)
    assert jax.jit(curriculum_update)(cur, d, 1.0, 0.7).dtype == jnp.float32


def test_batch_must_hold_whole_trajectories():
    with pytest.raises(ParamError, match="multiple of num_envs"):
        validate(PPOParams(num_envs=64, batch_size=16, num_minibatches=2))
    p = PPOParams()
    assert p.env_steps_per_training_step == p.batch_size * p.num_minibatches * p.unroll_length


def _two_robot_learner(p):
    from vbl.agents.ppo_inputs import InputEnv, InputParams
    from vbl.envs.brax_adapter import BraxAdapter, with_difficulty
    from vbl.envs.shoot_pass import ShootPassEnv

    ienv = InputEnv(ShootPassEnv("select"), "current")
    lrn = make_ppo_learner(lambda ep, d: BraxAdapter(ienv, with_difficulty(ep, d)),
                           ienv.observation_shape[0], ienv.num_actions, p)
    base = ienv.env.default_params.replace(max_steps=30)
    params = jax.vmap(lambda tp: InputParams(base.replace(task_pass=tp)))(
        jnp.array([False, True]))  # learner 0 shoots, learner 1 passes
    return lrn, params


@pytest.mark.slow  # compile-bound: 3-8 min on 2 cores
def test_vbl_ppo_on_shoot_and_pass_with_curriculum_drives_the_env():
    """vbl's PPO (brax's parts) for a few thousand steps on the shoot and the pass task (one
    vmapped program, after ``import vbl``): it finishes, and the curriculum's difficulty is
    the one the envs draw their next starts at."""
    import vbl  # noqa: F401

    p = PPOParams(net=PPONetParams(policy_hidden=(16,), value_hidden=(16,)), num_envs=8,
                  unroll_length=10, batch_size=8, num_minibatches=2, num_updates_per_batch=1,
                  steps_per_chunk=2, eval_envs=8,
                  curriculum=CurriculumParams(enabled=True, step=0.5, success_level=0.01))
    lrn, params = _two_robot_learner(p)
    carry = jax.jit(jax.vmap(lambda k, ep: lrn.init(k, ep, p)))(
        jax.random.split(jax.random.PRNGKey(0), 2), params)
    np.testing.assert_array_equal(carry.difficulty, 0.0)
    chunk = jax.jit(jax.vmap(lambda c: lrn.train_chunk(c, p)))
    for i in range(2):
        before = np.asarray(carry.difficulty)
        carry, m = chunk(carry)
        np.testing.assert_array_equal(m["env_steps"], (i + 1) * p.env_steps_per_chunk)
        want = np.where(np.asarray(m["level_success_rate"]) >= 0.01,
                        np.minimum(before + 0.5, 1.0), before)
        np.testing.assert_allclose(carry.difficulty, want, rtol=1e-6)
        np.testing.assert_array_equal(carry.env_state.info["difficulty"],
                                      np.broadcast_to(np.asarray(carry.difficulty)[:, None],
                                                      (2, p.num_envs)))
        for k in ("success_rate", "level_success_rate", "loss", "entropy"):
            assert np.all(np.isfinite(m[k])), k




def test_tracing_init_and_step_under_the_engines_64_bit_scope_warns_nothing():
    """The engine traces programs with 64-bit types on; brax's network and statistics
    initialisers, and its running statistics' update in the training step, then ask for
    float64, which JAX reported in a cold run. A fresh process: JAX caches dtype results,
    so a warning shows only the first time."""
    import subprocess
    import sys

    code = """
import jax
from vbl.engine.config import stack_traced
from vbl.engine.jax_setup import engine_precision
from vbl.programs.ppo_program import make_shooting_program
from vbl.engine.registry import get
cfg = get("ppo_shooting").default_config
with engine_precision():
    prog = make_shooting_program(cfg)
    c = jax.tree.map(lambda x: x[0], stack_traced([cfg]))
    carry = jax.eval_shape(lambda k: prog.init(k, c), jax.random.PRNGKey(0))
    jax.eval_shape(lambda cr: prog.step(cr, c), carry)
"""
    run = subprocess.run([sys.executable, "-W", "error::UserWarning", "-c", code],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
