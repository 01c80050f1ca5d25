"""The state maps of the one tabular learner (vbl.agents.state_maps) against independent truth.

* GridMap: the hand-built Section 2 vectors of tests/test_grid_space.py map to their
  hand-computed states, through the map and its config section; it perceives its state.
* CVAMap: on fixed observations of the moving-target env, the index and the perceived
  index equal a NumPy reference written here (filter sums over the raw histories, z-scored
  nearest code), the perceived one without the command terms.
* The macro rule: on a CVA map whose command terms change alone (the world stands still),
  a held primitive does not end its action; with the index as the stop key it would.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.agents.cva_state import CVAStateParams
from vbl.agents.state_maps import CVAMap, GridMap
from vbl.envs.macro import MacroActionParams, MacroWrapper, macro_env_params
from vbl.envs.shooting import ShootingEnv
from vbl.envs.wrappers import (
    HistoryFilterWrapper,
    HistoryParams,
    LinearFilter,
    QuantizeParams,
    QuantizeWrapper,
)
from vbl.spaces.grid import GridParams
from vbl.spaces.quantize import Quantizer, QuantizerParams, quantize
from vbl.sysid.params import CVAParams

sys.path.insert(0, str(Path(__file__).parent))
from moving_target_env import MovingTargetEnv  # noqa: E402
from test_grid_space import CASES  # noqa: E402


def test_grid_map_indexes_hand_built_vectors():
    smap = GridMap(ShootingEnv())
    c = SimpleNamespace(grid=GridParams())
    x = jnp.asarray(np.stack([obs for obs, _ in CASES]))
    got = jax.vmap(lambda o: smap.index(o, c))(x)
    np.testing.assert_array_equal(got, [s for _, s in CASES])
    np.testing.assert_array_equal(jax.vmap(lambda o: smap.perceived(o, c))(x), got)
    assert smap.num_states == 319 and smap.prepare(jax.random.PRNGKey(0), c) == ()
    # the boundaries are the learner's config: a wider orientation cut moves the first case
    # (orientation 0.0, frontal) nowhere, the third (0.3, right) to frontal
    wide = SimpleNamespace(grid=GridParams(orient_lower=-0.5, orient_upper=0.5))
    assert int(smap.index(x[2], wide)) == int(got[2]) - 1


def _numpy_index(qz: Quantizer, x: np.ndarray) -> int:
    """Nearest code of the z-scored vector (method 'vq'), lowest index on ties."""
    z = (x - np.asarray(qz.mean, np.float64)) / np.asarray(qz.scale, np.float64)
    d = np.sum((np.asarray(qz.codebook, np.float64) - z) ** 2, axis=1)
    return int(np.argmin(d))


def test_cva_map_index_and_perceived_against_numpy():
    env = MovingTargetEnv()
    p = CVAStateParams(state="cva", objects=("target",), n_used=2, collect_steps=600,
                       ident=CVAParams(lag=2),
                       quantizer=QuantizerParams(method="vq", num_codes=64, kmeans_iters=5))
    smap = CVAMap(env, p)
    c = SimpleNamespace(cva=p, env=env.default_params)
    models, qz, use_cva = jax.jit(lambda k: smap.prepare(k, c))(jax.random.PRNGKey(4))
    # the target barely answers the commands: give the command terms weight of their own
    rng = np.random.default_rng(0)
    models = (models[0].replace(Uu=jnp.asarray(rng.normal(size=models[0].Uu.shape),
                                               jnp.float32)),)
    fitted = (models, qz, use_cva)
    ep = smap.env_params(fitted, env.default_params)

    def run(key):
        obs, st = smap.env.reset(key, ep)

        def body(st, k):
            k_a, k_s = jax.random.split(k)
            a = jax.random.randint(k_a, (), 0, env.num_actions)
            obs, st, *_ = smap.env.step(k_s, st, a, ep)
            return st, (obs, st.hist_u[0], st.hist_y[0])

        return jax.lax.scan(body, st, jax.random.split(key, 40))[1]

    obs, hu, hy = jax.jit(run)(jax.random.PRNGKey(5))
    f = models[0]
    uu, uy = np.asarray(f.Uu, np.float64), np.asarray(f.Uy, np.float64)   # (2, lag, m|q)
    changed = 0
    for t in range(40):
        un = (np.asarray(hu[t], np.float64) - np.asarray(f.u_mean)) / np.asarray(f.u_scale)
        yn = (np.asarray(hy[t], np.float64) - np.asarray(f.y_mean)) / np.asarray(f.y_scale)
        world = sum(uy[:, j] @ yn[j] for j in range(yn.shape[0]))
        state = world + sum(uu[:, j] @ un[j] for j in range(1, un.shape[0]))  # u(t) not chosen
        np.testing.assert_allclose(np.asarray(obs["state"][t]), state, rtol=1e-4, atol=1e-4)
        assert int(smap.index({k: v[t] for k, v in obs.items()}, c)) == _numpy_index(qz, state)
        assert int(smap.perceived({k: v[t] for k, v in obs.items()}, c)) == _numpy_index(
            qz, world)
        changed += _numpy_index(qz, state) != _numpy_index(qz, world)
    assert changed > 5  # the perceived index leaves the command terms out
    out = smap.describe(fitted)
    assert set(out) == {"lag_target", "n_target"} and float(out["lag_target"]) == 2.0


class StillWorld:
    """One observed object that never moves; ``info["u"]`` is the command (-1, 0 or +1)."""

    num_actions = 3
    obs_slices = {"thing": slice(0, 1)}
    default_params = ()

    def reset(self, key, params):
        return jnp.zeros((1,), jnp.float32), jnp.int32(0)

    def step(self, key, state, action, params):
        u = (jnp.asarray(action, jnp.float32) - 1.0)[None]
        return (jnp.zeros((1,), jnp.float32), state + 1, jnp.float32(0.0), jnp.bool_(False),
                jnp.bool_(False), {"u": u, "success": jnp.bool_(False)})


def test_a_command_alone_does_not_end_the_action():
    """The state is the last command (a filter with only a command term), cut into 3 bins:
    holding a new primitive changes the index at once, the world (the perceived index) never,
    so the action runs to max_repeats; with the index as the stop key it ends after one."""
    hist = HistoryFilterWrapper(StillWorld(), ("thing",), 2, 1, (1,), "cva", world=True)
    env = QuantizeWrapper(hist, quantize)
    filt = LinearFilter(Uu=jnp.array([[[0.0], [1.0]]]), Uy=jnp.zeros((1, 2, 1)),
                        u_mean=jnp.zeros(1), u_scale=jnp.ones(1), y_mean=jnp.zeros(1),
                        y_scale=jnp.ones(1))
    qz = Quantizer(lo=jnp.array([-1.0]), hi=jnp.array([1.0]), mean=jnp.zeros(1),
                   scale=jnp.ones(1), codebook=jnp.zeros((1, 1)), method="bins", bins=3)
    ep = QuantizeParams(HistoryParams((), (filt,)), qz)
    macro = MacroActionParams(mode="async", max_repeats=5)
    wp = macro_env_params(ep, macro, 0.9)

    def lengths(perceive):
        w = MacroWrapper(env, lambda o: o["index"], macro,
                         perceive_fn=(lambda o: o["perceived"]) if perceive else None)
        obs, st = w.reset(jax.random.PRNGKey(0), wp)
        ends = []
        for i in range(6):   # command +1 (action 2) from rest: u(t-1) goes 0 -> 1
            obs, st, _, _, _, info = w.step(jax.random.PRNGKey(i), st, jnp.int32(2), wp)
            ends.append(bool(info["macro"]["ended"]))
        return ends, int(obs["index"]), int(obs["perceived"])

    ends, index, perceived = lengths(perceive=True)
    assert ends == [False, False, False, False, True, False]   # max_repeats = 5
    assert (index, perceived) == (2, 1)                         # u = +1: top bin; world: 0
    ends, *_ = lengths(perceive=False)
    assert ends[0]                                              # the command changed the index


def test_command_dim_is_the_length_of_a_step_command():
    """Each env's declared command length equals that of ``info["u"]`` after one abstract
    step, also under the velocity oracle; an env without a command is refused."""
    from vbl.agents.cva_state import command_dim
    from vbl.envs.shoot_pass import ShootPassEnv
    from vbl.envs.wrappers import BallVelocityOracle
    from vbl.params import ParamError

    key = jax.random.PRNGKey(0)
    for env in (ShootPassEnv("shoot"), BallVelocityOracle(ShootPassEnv("pass")),
                MovingTargetEnv()):
        ep = env.default_params
        _, st = jax.eval_shape(env.reset, key, ep)
        info = jax.eval_shape(lambda s, env=env, ep=ep: env.step(key, s, jnp.int32(0), ep),
                              st)[5]
        assert command_dim(env) == int(np.prod(info["u"].shape))
    with pytest.raises(ParamError, match="command_dim"):
        command_dim(ShootingEnv())
