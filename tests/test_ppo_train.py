"""The PPO learner's curriculum rule and parameter checks (the learner itself runs in the
ppo_comparator experiment and benchmarks/ppo_throughput.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.agents.ppo_train import CurriculumParams, PPOParams, curriculum_update
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
