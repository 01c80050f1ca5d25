"""Tables 1 and 3 as engine programs (vbl.programs.identification): a sweep over a traced
parameter is one program, and the per-seed numbers of a run equal ``vbl.sysid.identify`` on
the same data sets, collected again outside the program with ``collect_one`` and the
documented keys (learner key ``k``: scenario ``s`` from ``fold_in(k, s)``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.engine import get, run_experiment
from vbl.engine.config import traced_dtype
from vbl.engine.jax_setup import engine_precision
from vbl.engine.runner import resolve
from vbl.engine.sweep import learner_keys, make_plan
from vbl.envs.collect import FOCUS, CollectData, collect_one, id_outputs
from vbl.envs.other_agents import BEHAVIOURS
from vbl.params import replace_path
from vbl.programs.identification import OBJECT, TABLE1_ROWS, slug, table1_scenarios
from vbl.sysid import identify

SMALL = {"collect.num_steps": 200, "ident.lag_max": 2}  # N >= 161 for the goal at l <= 2
SWEEP = {"rows.ball_kick_prob": [0.1, 0.3]}
SEEDS = 2
BASE_SEED = 3


@pytest.fixture(scope="module")
def table1_run(tmp_path_factory):
    exp = get("table1_identification")
    res = run_experiment(exp, sets=SMALL, sweep=SWEEP, seeds=SEEDS, base_seed=BASE_SEED,
                         out=tmp_path_factory.mktemp("t1") / "run", quiet=True, plots=False)
    return exp, res


def test_a_sweep_is_one_program():
    exp = get("table1_identification")
    with engine_precision():
        config, sweep, seeds, _ = resolve(exp, sets=SMALL, sweep=SWEEP, seeds=SEEDS)
        plan = make_plan(exp, config, sweep, seeds)
    assert len(plan.groups) == 1 and plan.groups[0].num_learners == 2 * SEEDS


def _as_in_program(config):
    """The config's values in the dtypes a program sees (float32, int32, bool)."""
    return jax.tree.map(lambda x: np.asarray(x, traced_dtype(x)), config)


def _collect_again(key, params, s: int, one) -> CollectData:
    ids = (jnp.int32(BEHAVIOURS.index(params.other_behaviour)),
           jnp.int32(FOCUS.index(params.focus)))
    return one(jax.random.fold_in(key, s), params.replace(other_behaviour="random_walk",
                                                            focus="goal"), *ids)


@pytest.mark.slow  # compiles the program and the collection (minutes on 2 loaded cores)
def test_per_seed_numbers_equal_identify_on_the_same_data(table1_run):
    _, res = table1_run
    keys, _ = learner_keys(BASE_SEED, SEEDS)
    one = jax.jit(collect_one)
    for p, point in enumerate(res.points):
        cfg = res.config
        for path, v in point.items():
            cfg = replace_path(cfg, path, v)
        scen = table1_scenarios(_as_in_program(cfg.collect), _as_in_program(cfg.rows))
        for s, (row, params) in enumerate(scen.items()):
            sets = [_collect_again(keys[k], params, s, one) for k in range(SEEDS)]
            data = jax.tree.map(lambda *a: np.stack(a), *sets)
            ref = identify(np.asarray(data.u), id_outputs(data, OBJECT[row], cfg.y_unit),
                           cfg.ident)
            got = {q: res.final[f"{q}_{slug(row)}"][p] for q in ("l", "n", "logdet_R", "aic")}
            np.testing.assert_array_equal(got["l"], ref.lag, err_msg=row)
            np.testing.assert_array_equal(got["n"], ref.n, err_msg=row)
            np.testing.assert_allclose(got["logdet_R"], ref.logdet_R, rtol=1e-6, err_msg=row)
            np.testing.assert_allclose(got["aic"], ref.aic, rtol=1e-6, err_msg=row)


@pytest.mark.slow  # the same run as above
def test_the_swept_value_reaches_only_its_row(table1_run):
    """Common random numbers: rows that do not read rows.ball_kick_prob are the same at both
    sweep points, seed by seed; the ball row is not."""
    _, res = table1_run
    for row in TABLE1_ROWS:
        a, b = (res.final[f"logdet_R_{slug(row)}"][p] for p in (0, 1))
        assert np.array_equal(a, b) == (row != "ball"), row


@pytest.mark.slow  # the same run as above
def test_the_report_and_paper_rows_read_the_run(table1_run):
    exp, res = table1_run
    md = exp.report(res).markdown
    assert md.count("| goal |") == 2 and "ball_kick_prob=0.3" in md
    rows = exp.paper_rows(res)
    assert len(rows) == 2 * len(TABLE1_ROWS)
    assert all(r.ours.count(" / ") == 3 for r in rows)


def _pred_logdet_reference(model, u, y) -> float:
    """NumPy loop: log det of the covariance of the one-step errors y(t) - y_hat(t) of one
    CVA model (y_hat = y_mean + y_scale (C U p(t) + D u_n(t)), p(t) the last h normalised
    inputs then outputs, most recent first), over t >= h."""
    md = jax.tree.map(np.asarray, model)
    h, m, q = md.U.shape[1] // (u.shape[1] + y.shape[1]), u.shape[1], y.shape[1]
    hu, hy, err = np.zeros((h, m)), np.zeros((h, q)), []
    for t in range(len(u)):
        un, yn = (u[t] - md.u_mean) / md.u_scale, (y[t] - md.y_mean) / md.y_scale
        mu = md.U @ np.concatenate([hu.ravel(), hy.ravel()])
        err.append(y[t] - md.y_mean - md.y_scale * (md.C @ mu + md.D @ un))
        hu, hy = np.vstack([un, hu[:-1]]), np.vstack([yn, hy[:-1]])
    e = np.asarray(err)[h:]
    e = e - e.mean(0)
    return float(np.linalg.slogdet(e.T @ e / len(e))[1])


@pytest.mark.slow  # compiles Table 3's program and the collection (minutes on 2 loaded cores)
def test_table3_swap_test_equals_a_numpy_reference(tmp_path):
    """Each observer's ball model (identify on its row's data set) predicts both observers'
    held-out data sets (scenarios 8 and 9: the rows, then the held-out sets)."""
    from vbl.programs.identification import table3_scenarios

    res = run_experiment(get("table3_noisy"), sets=SMALL, seeds=SEEDS, base_seed=BASE_SEED,
                         out=tmp_path / "run", quiet=True, plots=False)
    cfg = res.config
    c = {k: _as_in_program(getattr(cfg, k)) for k in ("collect", "rows", "bodies", "noise")}
    scen = table3_scenarios(c["collect"], c["rows"], c["bodies"], c["noise"])
    names = list(scen)
    keys, _ = learner_keys(BASE_SEED, SEEDS)
    one = jax.jit(collect_one)
    for seed in range(SEEDS):
        models, tests = {}, {}
        for j, who in enumerate(("shooter", "passer")):
            row = f"{who}_ball"
            train = _collect_again(keys[seed], scen[row], names.index(row), one)
            test = _collect_again(keys[seed], scen[row], len(names) + j, one)
            ref = identify(np.asarray(train.u), id_outputs(train, "ball", cfg.y_unit),
                           cfg.ident, model_dtype=jnp.float64)
            assert res.final[f"l_{row}"][0, seed] == ref.lag
            assert res.final[f"n_{row}"][0, seed] == ref.n
            models[who] = ref.model
            tests[who] = (np.asarray(test.u, np.float64), id_outputs(test, "ball", cfg.y_unit))
        for data in models:
            for by in models:
                want = _pred_logdet_reference(models[by], *tests[data])
                got = res.final[f"swap_{data}_data_{by}_model"][0, seed]
                assert got == pytest.approx(want, rel=1e-6, abs=1e-9), (data, by)
