"""Static noise switches (``params.noise_on``): noise that is off is not computed, noise that
is on draws the same numbers as the one-hash layout of ``docs/world.md``.

* the compiled step's random numbers, counted in its jaxpr: the threefry words hashed and
  the inverse-error-function (normal) conversions, against the layout table of
  ``docs/world.md`` ("Random numbers");
* every block of the layout re-derived from ``jax.random.bits(key, (W,))`` of the whole
  layout (the peer the blocks must equal), for the env steps with every switch on and
  with some off;
* a stored reference: states after 30 auto-reset steps, recorded with the env before the
  switches existed (every noise source drawn), must not move;
* switch and std must agree (ParamError otherwise); the std stays traced (one program
  for a sweep over it), the switch is static.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.draws import normal
from vbl.engine.config import is_static
from vbl.envs.noise import NOISE_ON
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv
from vbl.params import ParamError
from vbl.world.physics import world_step

# the layout of docs/world.md ("Random numbers"), in words, written out here
SHOOTING = dict(slip=2, start=5, pixel=6)
SHOOT_PASS = dict(slip=4, aim=2, wobble=1, fresh=14, pixel=18)


def switched(p, **on):
    return p.replace(noise_on=p.noise_on.replace(**on))


def shooting_noisy():
    env = ShootingEnv()
    p = env.default_params
    p = p.replace(world=p.world.replace(robot=p.world.robot.replace(slip_std=0.1)),
                  camera=p.camera.replace(pixel_noise_std=2.0))
    return env, switched(p, slip=True, pixel=True)


def shoot_pass_noisy(task="shoot"):
    env = ShootPassEnv(task)
    p = env.default_params.replace(noise=NOISE_ON)
    return env, switched(p, slip=True, wobble=True, pixel=True)


def random_ops(fn, *args) -> tuple[int, int]:
    """(threefry words hashed, erf_inv equations) in the jaxpr of ``fn(*args)``,
    sub-jaxprs (loops, conds, jit calls) included."""
    closed = jax.make_jaxpr(fn)(*args)
    words, erfs = 0, 0

    def walk(jaxpr):
        nonlocal words, erfs
        for e in jaxpr.eqns:
            if e.primitive.name == "threefry2x32":
                words += int(np.prod(e.outvars[0].aval.shape))
            if e.primitive.name == "erf_inv":
                erfs += 1
            for v in e.params.values():
                for sub in v if isinstance(v, tuple | list) else (v,):
                    if hasattr(sub, "eqns"):
                        walk(sub)
                    elif hasattr(sub, "jaxpr") and hasattr(sub.jaxpr, "eqns"):
                        walk(sub.jaxpr)

    walk(closed.jaxpr)
    return words, erfs


def _one_step(env, p):
    _, st = env.reset(jax.random.key(0), p)
    return lambda k, s: env.step(k, s, jnp.int32(1), p), st


@pytest.mark.parametrize("on,words", [
    (dict(), SHOOTING["start"]),
    (dict(slip=True), SHOOTING["slip"] + SHOOTING["start"]),
    (dict(slip=True, pixel=True), sum(SHOOTING.values())),
])
def test_shooting_step_hashes_only_what_is_on(on, words):
    env = ShootingEnv()
    step, st = _one_step(env, switched(env.default_params, **on))
    w, erfs = random_ops(step, jax.random.key(1), st)
    assert w == words
    assert (erfs > 0) == bool(on), "normals are converted only for noise that is on"


@pytest.mark.parametrize("on,words", [
    (dict(aim=False), SHOOT_PASS["fresh"]),
    (dict(), SHOOT_PASS["aim"] + SHOOT_PASS["fresh"]),
    (dict(slip=True, wobble=True, pixel=True), sum(SHOOT_PASS.values())),
])
def test_shoot_pass_step_hashes_only_what_is_on(on, words):
    env = ShootPassEnv("shoot")
    p = env.default_params
    if on.get("aim") is False:
        p = p.replace(other=p.other.replace(aim_noise_deg=0.0))
    p = switched(p, **on)
    step, st = _one_step(env, p)
    w, erfs = random_ops(step, jax.random.key(1), st)
    assert w == words
    normals = sum(SHOOT_PASS[k] for k in ("slip", "aim", "wobble", "pixel")
                  if getattr(p.noise_on, k))
    assert (erfs > 0) == (normals > 0)


def test_noise_off_program_has_fewer_random_ops_than_before():
    """Default parameters (noise off): the step hashes fewer words than the whole layout
    (what the step drew when every source was always drawn) and converts no normal
    (shooting) or only the passer's aim (shoot and pass)."""
    env = ShootingEnv()
    step, st = _one_step(env, env.default_params)
    w, erfs = random_ops(step, jax.random.key(1), st)
    assert w < sum(SHOOTING.values()) and erfs == 0
    env = ShootPassEnv("shoot")
    step, st = _one_step(env, env.default_params)
    w, erfs = random_ops(step, jax.random.key(1), st)
    assert w < sum(SHOOT_PASS.values()) and erfs == 1


def _bits(key, n):
    return jax.random.bits(key, (n,), jnp.uint32)


def _assert_close(a, b, tol):
    """Equal up to the rounding of a compiled against an eager camera (a block of wrong
    words moves a value by about its noise std: metres or pixels)."""
    def check(x, y):
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype.kind == "f":
            np.testing.assert_allclose(x, y, rtol=tol, atol=tol)
        else:
            np.testing.assert_array_equal(x, y)

    jax.tree.map(check, a, b)


@pytest.mark.parametrize("pixel", [True, False])
def test_shooting_blocks_are_the_whole_layouts_words(pixel):
    env, p = shooting_noisy()
    if not pixel:
        p = switched(p.replace(camera=p.camera.replace(pixel_noise_std=0.0)), pixel=False)
    key = jax.random.key(7)
    _, st = env.reset(jax.random.key(3), p)
    a = jnp.int32(4)
    # step_env: slip, pixel
    b = _bits(key, SHOOTING["slip"] + SHOOTING["pixel"])
    obs, nst, *_ = jax.jit(env.step_env)(key, st, a, p)
    world, _ = world_step(st.world, a.reshape(1), p.world, normal(b[:2]).reshape(1, 2))
    _assert_close(nst.world, world, 1e-6)
    _assert_close(obs, env.get_obs(nst.replace(world=world), p,
                                   normal(b[2:]) if pixel else None), 1e-4)
    # step at the time limit (auto-reset): slip, start, pixel
    st = st.replace(step=jnp.int32(p.max_steps - 1))
    b = _bits(key, sum(SHOOTING.values()))
    obs, nst, _, _, truncated, _ = jax.jit(env.step)(key, st, a, p)
    assert bool(truncated)
    fresh = env.start_from_words(b[2:7], p)
    _assert_close(nst.world, fresh, 1e-6)
    _assert_close(obs, env.get_obs(nst.replace(world=fresh), p,
                                   normal(b[7:]) if pixel else None), 1e-4)


@pytest.mark.parametrize("task", ["shoot", "pass"])
def test_shoot_pass_blocks_are_the_whole_layouts_words(task):
    env, p = shoot_pass_noisy(task)
    key = jax.random.key(11)
    _, st = env.reset(jax.random.key(5), p)
    a = jnp.int32(1)
    n = SHOOT_PASS
    b = normal(_bits(key, n["slip"] + n["aim"] + n["wobble"] + n["pixel"]))
    obs, nst, *_ = jax.jit(env.step_env)(key, st, a, p)
    want, *_ = env._transition((b[:4], b[4:6], b[6:7]), st, a, p)
    _assert_close(nst, want, 1e-6)
    _assert_close(obs, env.get_obs(want, p, b[7:]), 1e-4)
    # auto-reset at the time limit: the fresh episode sits between transition and pixels
    st = st.replace(step=jnp.int32(p.max_steps - 1))
    w = _bits(key, sum(n.values()))
    obs, nst, _, terminated, truncated, _ = jax.jit(env.step)(key, st, a, p)
    assert bool(terminated | truncated)
    fresh = env._fresh(w[7:21], p)
    _assert_close(nst, fresh, 1e-6)
    _assert_close(obs, env.get_obs(fresh, p, normal(w[21:])), 1e-4)


@pytest.mark.slow  # two compiled 20-step programs of the two-robot env
def test_a_source_switched_off_leaves_the_other_draws_unchanged():
    """Pixel noise off: the same states as with it on (tire slip, aim, wobble and the
    starts keep their words), and the observation is the exact one."""
    env, p = shoot_pass_noisy()
    q = switched(p.replace(noise=p.noise.replace(image_std=0.0)), pixel=False)

    def run(p):
        _, st = jax.vmap(env.reset, (0, None))(jax.random.split(jax.random.key(2), 8), p)

        def body(st, t):
            ks = jax.random.split(jax.random.fold_in(jax.random.key(3), t), 8)
            o, st, *_ = jax.vmap(env.step, (0, 0, 0, None))(ks, st, (t + jnp.arange(8)) % 7, p)
            return st, o
        return jax.lax.scan(body, st, jnp.arange(20))

    st_p, obs_p = jax.jit(run)(p)
    st_q, obs_q = jax.jit(run)(q)
    _assert_close(st_p, st_q, 1e-6)  # two programs: equal up to rounding
    assert not np.array_equal(np.asarray(obs_p), np.asarray(obs_q))


# states after 30 auto-reset steps (8 envs, keys and actions as in _trajectory), recorded
# with the env that drew every noise source in every step (before the static switches;
# the two-robot rows since with the kick law of vbl.world.kick_velocity: a kick adds to
# the incoming ball velocity):
# [sum of robots (x, y, heading), sum of ball (x, y), sum of |ball velocity|] at steps
# 10, 20, 30
REFERENCE = {
    "pass": [[35.62605, 19.33807, 4.33181], [30.85669, 18.12327, 5.900111],
             [36.44592, 14.99656, 6.277341]],
    "shoot": [[36.68712, 19.39538, 0.0], [36.04757, 16.31158, 12.45017],
              [35.74538, 10.25124, 15.75627]],
    "shooting": [[-6.380939, 7.524741, 0.0], [-7.026217, 7.524741, 0.0],
                 [-5.347333, 7.524741, 0.0]],
}


def _trajectory(env, p, steps=30, batch=8):
    k0 = jax.random.key(42)

    def run(p):
        _, st = jax.vmap(env.reset, (0, None))(jax.random.split(k0, batch), p)

        def body(st, t):
            ks = jax.random.split(jax.random.fold_in(k0, t), batch)
            a = jax.random.randint(jax.random.fold_in(k0, 10_000 + t), (batch,), 0,
                                   env.num_actions)
            _, st, *_ = jax.vmap(env.step, (0, 0, 0, None))(ks, st, a, p)
            w = st.world
            return st, jnp.stack([w.robots.sum(), w.ball.sum(), jnp.abs(w.ball_vel).sum()])
        return jax.lax.scan(body, st, jnp.arange(steps))[1]

    return np.asarray(jax.jit(run)(p))[[9, 19, 29]]


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_noisy_states_match_the_recorded_reference(name):
    env, p = shooting_noisy() if name == "shooting" else shoot_pass_noisy(name)
    np.testing.assert_allclose(_trajectory(env, p), REFERENCE[name], rtol=1e-5, atol=1e-5)


def test_switch_and_std_must_agree():
    env = ShootingEnv()
    p = env.default_params
    with pytest.raises(ParamError, match="noise_on.slip"):
        env.validate(p.replace(world=p.world.replace(
            robot=p.world.robot.replace(slip_std=0.1))))
    with pytest.raises(ParamError, match="noise_on.pixel"):
        env.reset(jax.random.key(0), p.replace(camera=p.camera.replace(pixel_noise_std=1.0)))
    sp = ShootPassEnv("shoot")
    q = sp.default_params
    for field, switch in (("slip_std", "slip"), ("ecc_turn_std", "wobble"),
                          ("image_std", "pixel")):
        bad = q.replace(noise=q.noise.replace(**{field: 0.1}))
        with pytest.raises(ParamError, match=f"noise_on.{switch}"):
            sp.validate(bad)
        sp.validate(switched(bad, **{switch: True}))
    with pytest.raises(ParamError, match="noise_on.aim"):
        sp.validate(switched(q, aim=False))
    # a switch that is on with a zero std is allowed (a sweep over the std includes 0)
    sp.validate(switched(q, slip=True, wobble=True, pixel=True))
    # the centroid eccentricity draws nothing: no switch
    sp.validate(q.replace(noise=q.noise.replace(ecc_centroid=0.3)))


def test_switch_is_static_and_std_traced():
    """A sweep over a noise std is one program; each switch value is its own."""
    env, p = shooting_noisy()
    assert is_static(p, "noise_on.pixel") and not is_static(p, "camera.pixel_noise_std")
    traces = []

    def f(k, s, p):
        traces.append(p.noise_on)
        return env.step(k, s, jnp.int32(1), p)[0]

    _, st = env.reset(jax.random.key(0), p)
    g = jax.jit(f)
    for std in (0.0, 1.0, 2.0):
        g(jax.random.key(1), st, p.replace(camera=p.camera.replace(pixel_noise_std=std)))
    assert len(traces) == 1
    g(jax.random.key(1), st, switched(p.replace(camera=p.camera.replace(pixel_noise_std=0.0)),
                                      pixel=False))
    assert len(traces) == 2
