"""The env base (vbl.envs.base.TaskEnv) on a toy task whose every number is known: a
counter episode of EPISODE steps whose fresh state is read from the random words, so the
auto-reset and the random layout are checked against jax.random.bits directly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from vbl.draws import uniform01
from vbl.envs.base import NoiseOn, Observer, TaskEnv
from vbl.params import ParamError, param, section
from vbl.world.params import WorldParams
from vbl.world.physics import WorldState

EPISODE = 3
FRESH = 3  # words of a fresh episode: the robot pose
SLIP = 2  # words of a transition's slip block


@struct.dataclass
class ToyParams:
    world: WorldParams = section(WorldParams, doc="physics")
    noise_on: NoiseOn = section(NoiseOn, doc="switches")
    max_steps: int = param(EPISODE, doc="episode length", static=True, ge=1)
    obs_source: str = param("analytic", doc="the base's observation source switch",
                            static=True, choices=("analytic", "pixels"))


@struct.dataclass
class ToyState:
    world: WorldState
    step: jax.Array


class ToyEnv(TaskEnv, params=ToyParams, state=ToyState, fresh_words=FRESH, pixel_noise_dim=1,
             option=("kind", ("a", "b"))):
    name = "Toy"
    num_actions = 2
    action_labels = ("stay", "go")
    observation_shape = (4,)

    def __init__(self, kind="a", params=None):
        super().__init__(kind, params)

    def transition_blocks(self, params):
        return ((SLIP, params.noise_on.slip),)

    def _fresh(self, words, params):
        z = jnp.zeros(2, jnp.float32)
        world = WorldState(robots=uniform01(words).reshape(1, 3), ball=z, ball_vel=z,
                           scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))
        return ToyState(world=world, step=jnp.zeros((), jnp.int32))

    def _transition(self, eps, state, action, params):
        assert eps == (None,)  # slip is off: its block is not drawn
        step = state.step + 1
        done = step >= params.max_steps
        info = dict(episode_done=done, episode_length=step)
        return (state.replace(step=step), jnp.asarray(action, jnp.float32), done,
                jnp.zeros((), bool), info)

    def get_obs(self, state, params, eps=None):
        return jnp.append(state.world.robots[0], state.step.astype(jnp.float32))


def _fresh_pose(key, start, total):
    """The fresh pose from the words [start, start + FRESH) of the call's layout."""
    return np.asarray(uniform01(jax.random.bits(key, (total,), jnp.uint32)[start:start + FRESH]))


def test_reset_draws_the_first_words_and_observes_its_state():
    env = ToyEnv()
    key = jax.random.key(1)
    obs, state = env.reset(key)
    np.testing.assert_array_equal(state.world.robots[0], _fresh_pose(key, 0, FRESH + 1))
    np.testing.assert_array_equal(obs, [*np.asarray(state.world.robots[0]), 0.0])
    s2, eps = env.reset_state(key)
    assert eps is None  # pixel noise off
    np.testing.assert_array_equal(env.get_obs(s2, env.default_params), obs)


def test_step_auto_resets_at_the_episode_end_with_the_fresh_words_after_the_transition():
    env = ToyEnv()
    _, state = env.reset(jax.random.key(0))
    step = jax.jit(env.step)
    for t in range(1, EPISODE + 1):
        key = jax.random.key(10 + t)
        obs, nstate, reward, terminated, truncated, info = step(key, state, jnp.int32(1))
        assert float(reward) == 1.0 and int(info["episode_length"]) == t
        assert bool(terminated) == (t == EPISODE) and not bool(truncated)
        if t < EPISODE:  # same episode: the counter moves, the pose stays
            assert int(nstate.step) == t
            np.testing.assert_array_equal(nstate.world.robots, state.world.robots)
        else:  # reset: a fresh episode from the words after the slip block
            assert int(nstate.step) == 0
            np.testing.assert_array_equal(nstate.world.robots[0],
                                          _fresh_pose(key, SLIP, SLIP + FRESH + 1))
        np.testing.assert_array_equal(obs, env.get_obs(nstate, env.default_params))
        state = nstate


def test_step_env_does_not_reset():
    env = ToyEnv()
    _, state = env.reset(jax.random.key(0))
    state = state.replace(step=jnp.int32(EPISODE - 1))
    _, nstate, _, terminated, *_ = env.step_env(jax.random.key(3), state, jnp.int32(0))
    assert bool(terminated) and int(nstate.step) == EPISODE
    np.testing.assert_array_equal(nstate.world.robots, state.world.robots)


def test_checks_outside_jit_and_none_inside():
    env = ToyEnv("b")
    assert repr(env) == "ToyEnv(kind='b', params=['world', 'noise_on', 'max_steps', 'obs_source'])"
    _, state = env.reset(jax.random.key(0))
    key = jax.random.key(1)
    with pytest.raises(ValueError, match=r"\[0, 1\] \(stay, go\)"):
        env.step(key, state, jnp.int32(2))
    with pytest.raises(ValueError, match="ToyState"):
        env.step(key, state.world, jnp.int32(0))
    bad = state.replace(world=state.world.replace(robots=jnp.zeros((2, 3))))
    with pytest.raises(ValueError, match=r"expected \(1, 3\) / \(2,\)"):
        env.step(key, bad, jnp.int32(0))
    with pytest.raises(ParamError, match="ToyParams"):
        env.reset(key, WorldParams())
    with pytest.raises(ParamError, match="slip_std"):
        env.validate(ToyParams(world=WorldParams().replace(
            robot=WorldParams().robot.replace(slip_std=-1.0))))
    with pytest.raises(ValueError, match=r"kind='c' is not allowed; choose one of \['a', 'b'\]"):
        ToyEnv("c")
    # traced action out of range: no check inside jit
    jax.jit(env.step)(key, state, jnp.int32(5))


def test_the_constructor_refuses_bad_default_parameters():
    """params= of the constructor become every call's defaults: checked there, as
    validate() checks them (type, bounds)."""
    with pytest.raises(ParamError, match="ToyParams"):
        ToyEnv("a", WorldParams())
    with pytest.raises(ParamError, match="slip_std"):
        ToyEnv("a", ToyParams(world=WorldParams().replace(
            robot=WorldParams().robot.replace(slip_std=-1.0))))
    assert ToyEnv("a", ToyParams(max_steps=5)).default_params.max_steps == 5


def test_a_state_with_a_batch_of_balls_is_refused():
    """One env's state holds one ball (2,): a batch of balls outside vmap is refused, as a
    batch of robots is."""
    env = ToyEnv()
    _, state = env.reset(jax.random.key(0))
    bad = state.replace(world=state.world.replace(ball=jnp.zeros((4, 2))))
    for call in (env.step, env.step_env):
        with pytest.raises(ValueError, match=r"ball \(4, 2\); expected \(1, 3\) / \(2,\)"):
            call(jax.random.key(1), bad, jnp.int32(0))


class _PixelToy(ToyEnv, params=ToyParams, state=ToyState, fresh_words=FRESH,
               pixel_noise_dim=1, option=("kind", ("a", "b"))):
    """ToyEnv with a camera image of H x W = 12 x 16 (rows differ from columns)."""

    def observer(self, params):
        rp = params.pixels.render
        return Observer(features=None, from_image=None, image_noise_std=0.1,
                        image=lambda state: jnp.full((rp.height, rp.width, 3), 0.5,
                                                     jnp.float32))


def test_image_shape_and_pixel_noise_are_the_camera_images():
    """image_shape is (H, W, 3) of the image the env renders; under pixels its noise has one
    normal per channel of each pixel, laid out as that image."""
    from types import SimpleNamespace

    from vbl.vision.render import RenderParams

    env = _PixelToy()
    params = SimpleNamespace(pixels=SimpleNamespace(render=RenderParams(width=16, height=12)),
                             obs_source="pixels")
    _, state = env.reset(jax.random.key(0))
    assert env.image_shape(params) == env.observer(params).image(state).shape == (12, 16, 3)
    assert env.pixel_noise_size(params) == 12 * 16 * 3
    eps = jnp.zeros(env.pixel_noise_size(params)).at[16 * 3 + 2].set(1.0)  # row 1, col 0, B
    img = np.asarray(env.get_pixels(state, params, eps))
    assert img.shape == (12, 16, 3) and img[1, 0, 2] == round(255 * 0.6) and \
        (img == 128).sum() == img.size - 1


def test_a_task_must_declare_its_parts():
    with pytest.raises(TypeError):
        class Incomplete(TaskEnv, params=ToyParams, state=ToyState):  # noqa: F841
            pass


class TruncatingToyEnv(ToyEnv, params=ToyParams, state=ToyState, fresh_words=FRESH,
                       pixel_noise_dim=1, option=("kind", ("a", "b"))):
    """The toy whose episodes end by the time limit only: truncated, never terminated."""

    def _transition(self, eps, state, action, params):
        state, reward, done, _, info = super()._transition(eps, state, action, params)
        return state, reward, jnp.zeros((), bool), done, info


def test_step_auto_resets_after_a_truncation_too():
    env = TruncatingToyEnv()
    _, state = env.reset(jax.random.key(0))
    step = jax.jit(env.step)
    for t in range(1, 2 * EPISODE + 1):
        key = jax.random.key(20 + t)
        _, nstate, _, terminated, truncated, _ = step(key, state, jnp.int32(0))
        end = t % EPISODE == 0
        assert not bool(terminated) and bool(truncated) == end
        assert int(nstate.step) == (0 if end else t % EPISODE)
        if end:  # a fresh episode from the words after the slip block
            np.testing.assert_array_equal(nstate.world.robots[0],
                                          _fresh_pose(key, SLIP, SLIP + FRESH + 1))
        state = nstate


class RuledToyEnv(ToyEnv, params=ToyParams, state=ToyState, fresh_words=FRESH,
                  pixel_noise_dim=1, option=("kind", ("a", "b"))):
    """The toy with a consistency rule of its own: episodes of at most 5 steps."""

    def check_params(self, params):
        if params.max_steps > 5:
            raise ParamError(f"max_steps={params.max_steps}: this task allows at most 5")


def test_a_tasks_own_rules_are_checked_outside_jit():
    env = RuledToyEnv()
    long = env.default_params.replace(max_steps=6)
    for call in (lambda: env.reset(jax.random.key(0), long),
                 lambda: env.step(jax.random.key(0), env.reset(jax.random.key(0))[1],
                                  jnp.int32(0), long)):
        with pytest.raises(ParamError, match="at most 5"):
            call()
    env.reset(jax.random.key(0), env.default_params.replace(max_steps=5))


class _NoisyFeaturesToy(ToyEnv, params=ToyParams, state=ToyState, fresh_words=FRESH,
                        pixel_noise_dim=1, option=("kind", ("a", "b"))):
    """The toy observed by the base's get_obs: its features are the pose plus the pixel
    noise's one normal (0 without noise)."""

    def observer(self, params):
        def features(state, eps):
            return jnp.append(state.world.robots[0], 0.0 if eps is None else eps[0])
        return Observer(features=features, image=None, from_image=None)

    get_obs = TaskEnv.get_obs


def test_reset_observes_with_the_pixel_noise_drawn_after_the_fresh_words():
    """noise_on.pixel on: reset's obs is get_obs(state, params, eps) with eps the normal of
    the word after the fresh episode's words, not the noise-free obs."""
    from vbl.draws import normal

    env = _NoisyFeaturesToy()
    params = env.default_params.replace(noise_on=NoiseOn(pixel=True))
    key = jax.random.key(4)
    obs, state = env.reset(key, params)
    state2, eps = env.reset_state(key, params)
    words = jax.random.bits(key, (FRESH + 1,), jnp.uint32)
    np.testing.assert_array_equal(eps, normal(words[FRESH:]))
    np.testing.assert_array_equal(state2.world.robots[0], _fresh_pose(key, 0, FRESH + 1))
    np.testing.assert_array_equal(obs, env.get_obs(state, params, eps))
    clean = np.asarray(env.get_obs(state, params))
    assert float(eps[0]) != 0.0 and not np.array_equal(obs, clean)
    np.testing.assert_array_equal(obs[:3], clean[:3])
    assert obs[3] == eps[0]


def test_step_observes_the_selected_state_with_its_pixel_noise():
    from vbl.draws import normal

    env = _NoisyFeaturesToy()
    params = env.default_params.replace(noise_on=NoiseOn(pixel=True))
    _, state = env.reset(jax.random.key(0), params)
    for t in range(1, EPISODE + 1):
        key = jax.random.key(30 + t)
        obs, nstate, *_ = env.step(key, state, jnp.int32(0), params)
        # words: slip block (off), fresh words, then the pixel noise's normal
        words = jax.random.bits(key, (SLIP + FRESH + 1,), jnp.uint32)
        eps = normal(words[SLIP + FRESH:])
        np.testing.assert_array_equal(obs, env.get_obs(nstate, params, eps))
        obs_env, *_ = env.step_env(key, state, jnp.int32(0), params)
        assert obs_env[3] == normal(jax.random.bits(key, (SLIP + 1,), jnp.uint32)[SLIP:])[0]
        state = nstate


def test_the_camera_image_has_no_image_noise_under_the_analytic_source():
    """Image noise belongs to obs_source="pixels": under "analytic" get_pixels returns the
    clean image whatever eps it is given."""
    from types import SimpleNamespace

    from vbl.vision.render import RenderParams

    env = _PixelToy()
    render = RenderParams(width=16, height=12)
    analytic = SimpleNamespace(pixels=SimpleNamespace(render=render), obs_source="analytic")
    _, state = env.reset(jax.random.key(0))
    assert env.pixel_noise_size(analytic) == 1
    for eps in (jnp.ones(1), jnp.full(12 * 16 * 3, 3.0)):
        img = np.asarray(env.get_pixels(state, analytic, eps))
        assert img.shape == (12, 16, 3) and np.all(img == 128)
    pixels = SimpleNamespace(pixels=SimpleNamespace(render=render), obs_source="pixels")
    img = np.asarray(env.get_pixels(state, pixels, jnp.full(12 * 16 * 3, 3.0)))
    assert np.all(img == round(255 * 0.8))
