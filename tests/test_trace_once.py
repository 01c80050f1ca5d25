"""The cameras and the physics step are traced once per program, however often it calls them.

``section2_features``, ``section3_features`` and ``world_step`` are ``jax.jit`` functions:
a program that resets and steps an env, at several vmap depths, runs their Python once
and batches the traced function, instead of tracing it again at every call site (the
trace CPU time per program: ``benchmarks/compile_time.py``, docs/findings/compile_cost.md).
Each test counts the calls of a helper their body calls once.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

import vbl.vision.section2 as section2
import vbl.vision.section3 as section3
import vbl.world.physics as physics
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv


def _counting(monkeypatch, module, name: str) -> list[int]:
    """Count the calls of ``module.name`` (a helper looked up at call time)."""
    calls, inner = [0], getattr(module, name)

    def counted(*a, **k):
        calls[0] += 1
        return inner(*a, **k)

    monkeypatch.setattr(module, name, counted)
    return calls


def _program(env):
    """A program that resets and steps one env (the camera at both, the physics step in
    the step), then the same for 2 x 3 envs under two vmaps: each function is called at
    two or four places, at vmap depths 0 and 2."""
    p = env.default_params

    def one(key):
        obs, st = env.reset(key, p)
        obs2, *_ = env.step(key, st, jnp.int32(0), p)
        return obs, obs2

    def program(keys):
        first = one(keys[0, 0])
        many = jax.vmap(jax.vmap(one))(keys)
        return first, many

    return program, jax.random.split(jax.random.PRNGKey(0), 6).reshape(2, 3, 2)


@pytest.mark.parametrize("env, module, function, helper", [
    (ShootPassEnv("pass"), section3, "section3_features", "_view"),
    (ShootingEnv(), section2, "section2_features", "camera_frame"),
    (ShootPassEnv("shoot"), physics, "world_step", "_consts"),
])
def test_traced_once_per_program(monkeypatch, env, module, function, helper):
    calls = _counting(monkeypatch, module, helper)
    getattr(module, function).clear_cache()  # traced by an earlier test: trace it again
    program, keys = _program(env)
    jax.make_jaxpr(program)(keys)
    assert calls[0] == 1, f"{module.__name__}.{helper} traced {calls[0]} times"

