"""Batched identification-data collection (vbl.envs.collect)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.envs.collect import (
    CollectData,
    CollectParams,
    collect,
    collect_many,
    collect_one,
    collect_scenarios,
    id_outputs,
    object_outputs,
    observer_action,
)
from vbl.params import ParamError
from vbl.world.physics import make_state
from vbl.world.robots import FOUR_WHEEL_U

N = 30
BATCH = 3


@pytest.fixture(scope="module")
def scen():
    base = CollectParams(num_steps=N)
    return [base.replace(focus="goal", other_behaviour="stationary"),
            base.replace(focus="other", other_behaviour="random_walk")]


@pytest.fixture(scope="module")
def data(scen):
    return collect_many(jax.random.PRNGKey(0), scen, BATCH)


@pytest.mark.slow  # compiles the collection scan (minutes on a loaded 2-core box)
def test_shapes_dtypes(data):
    for d in data:
        assert d.u.shape == (BATCH, N, 2) and d.ball.shape == (BATCH, N, 4)
        assert d.goal.shape == (BATCH, N, 11) and d.other.shape == (BATCH, N, 5)
        assert d.visible.shape == (BATCH, N, 3)
        for x in (d.u, d.ball, d.goal, d.other, d.visible):
            assert x.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(x)))
        rows = {tuple(r) for r in np.asarray(d.u).reshape(-1, 2).astype(int).tolist()}
        assert rows <= {tuple(r) for r in FOUR_WHEEL_U.tolist()}


@pytest.mark.slow  # compiles the collection scan (minutes on a loaded 2-core box)
def test_deterministic_and_keyed(scen, data):
    again = collect_many(jax.random.PRNGKey(0), scen, BATCH)
    for a, b in zip(data, again, strict=True):
        np.testing.assert_array_equal(a.goal, b.goal)
        np.testing.assert_array_equal(a.u, b.u)
    other = collect_many(jax.random.PRNGKey(1), scen, BATCH)
    assert not np.array_equal(np.asarray(other[0].u), np.asarray(data[0].u))
    # data sets within a batch differ
    assert not np.array_equal(np.asarray(data[0].u[0]), np.asarray(data[0].u[1]))


@pytest.mark.slow  # compiles the collection scan (minutes on a loaded 2-core box)
def test_focus_kept_in_view(data):
    assert np.asarray(data[0].visible)[..., 1].mean() > 0.9     # goal row: goal visible
    assert np.asarray(data[1].visible)[..., 2].mean() > 0.9     # other row: robot visible


def test_observer_action_keeps_view():
    p = CollectParams(focus="goal", keep_bearing_deg=20.0)
    # goal far on the left (bearing ~ +60 deg): only FL (2) or BR (6) turn towards it
    w = make_state([[4.11 - 1.0, -np.sqrt(3.0), 0.0], [0.0, 0.0, 0.0]], [0.0, 1.0])
    u = np.arange(1000) / 1000  # uniform draws on a grid of [0, 1)
    acts = np.asarray(jax.vmap(lambda x: observer_action(x, w, p))(jnp.asarray(u, jnp.float32)))
    assert set(acts.tolist()) == {2, 6}
    assert np.mean(acts == 2) == pytest.approx(0.5, abs=0.01)  # uniform among the allowed
    # goal ahead and too close: no forward action
    w = make_state([[3.5, 0.0, 0.0], [0.0, 0.0, 0.0]], [0.0, 1.0])
    acts = np.asarray(jax.vmap(lambda x: observer_action(x, w, p))(jnp.asarray(u, jnp.float32)))
    assert all(FOUR_WHEEL_U[a][0] <= 0 for a in set(acts.tolist()))
    assert len(set(acts.tolist())) == sum(FOUR_WHEEL_U[a][0] <= 0 for a in range(7))


def test_id_outputs():
    y = np.zeros((1, 2, 5), np.float32)
    y[..., 4] = 400.0
    y[..., 0] = 8.0
    d = CollectData(u=np.zeros((1, 2, 2)), ball=np.zeros((1, 2, 4)), goal=np.zeros((1, 2, 11)),
                    other=y, visible=np.ones((1, 2, 3)))
    out = id_outputs(d, "other", 4.0)
    assert out.dtype == np.float64
    np.testing.assert_allclose(out[0, 0], [2.0, 0, 0, 0, 5.0])
    with pytest.raises(ValueError, match="object"):
        id_outputs(d, "referee", 1.0)
    with pytest.raises(ValueError, match="y_unit"):
        id_outputs(d, "other", 0.0)


def test_object_outputs_in_jax_equal_numpy():
    """The jittable outputs (inside programs) equal id_outputs' NumPy ones."""
    y = np.random.default_rng(0).uniform(-50.0, 400.0, (3, 7, 11))
    want = id_outputs(CollectData(u=None, ball=None, goal=y, other=None, visible=None),
                      "goal", 4.0)
    with jax.enable_x64(True):
        got = jax.jit(lambda a, unit: object_outputs(a, "goal", unit))(jnp.asarray(y), 4.0)
        np.testing.assert_allclose(np.asarray(got), want, rtol=1e-15)


@pytest.mark.slow  # compiles the collection scan twice more
def test_collect_scenarios_is_collect_one_per_scenario(scen):
    """One learner's data sets: scenario s is collect_one(fold_in(key, s), scenario s), with
    the scenarios' own (static) behaviour and focus. The actions are equal; the float32
    features to rounding (one compiled program against op-by-op dispatch)."""
    key = jax.random.PRNGKey(7)
    got = jax.jit(lambda k: collect_scenarios(k, scen))(key)
    for s, sc in enumerate(scen):
        want = collect_one(jax.random.fold_in(key, s), sc)
        np.testing.assert_array_equal(got.u[s], want.u)
        np.testing.assert_allclose(got.other[s], want.other, rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(got.goal[s], want.goal, rtol=1e-5, atol=1e-3)


def test_bad_inputs(scen):
    k = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="batch"):
        collect(k, scen[0], 0)
    with pytest.raises(ParamError, match="CollectParams"):
        collect(k, {"num_steps": 3}, 2)
    with pytest.raises(ParamError, match="static"):
        collect_many(k, [scen[0], scen[1].replace(num_steps=N + 1)], 2)
    with pytest.raises(ParamError, match="focus"):
        collect(k, scen[0].replace(focus="referee"), 2)
    with pytest.raises(ParamError, match="min_dist"):
        collect(k, scen[0].replace(min_dist=5.0, max_dist=1.0), 2)


@pytest.mark.slow  # compiles the collection scan once more (one scenario per call)
def test_grouping_does_not_change_the_data(scen, data):
    """Scenario s always uses fold_in(key, s): one call per scenario gives the same data."""
    one_by_one = collect_many(jax.random.PRNGKey(0), scen, BATCH, group=1)
    for a, b in zip(data, one_by_one, strict=True):
        np.testing.assert_array_equal(a.u, b.u)
        np.testing.assert_array_equal(a.goal, b.goal)


def test_bad_group_is_refused(scen):
    with pytest.raises(ValueError, match="group must be an int >= 1"):
        collect_many(jax.random.PRNGKey(0), scen, BATCH, group=0)
