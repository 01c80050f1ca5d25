"""A program's final evaluation that runs through its own training step.

* Engine (`Program.begin_final`, `final_steps`): on a toy program whose final steps draw
  from the final key, the runner's final row equals a hand computation from the keys of
  `vbl.engine.sweep.learner_keys`; the final steps log no chunk row, change no training
  metric, and the checkpoint keeps the training carry (resuming it repeats the final row);
  `finish` gives the same in one traced call, and `run_program` in its one loop (its
  totals summed over the training chunks only); inconsistent programs are refused.
* Tabular (`vbl.programs.tabular`): the final evaluation's every (policy, round) unit
  equals the runner's own `evaluate` of that round's starts with that unit's key, bit for
  bit, in layouts where a unit fills a sub-chunk, where units span steps and where the
  step has no curve sub-chunks; the metrics are the means over rounds of the units.
* A program inside another (Figure 5's map program and its grid baseline, slow): the
  outer program's final steps run the grid's final evaluation, whose metrics equal
  `finish` of the grid program, and its evaluation episodes are not counted as training.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401
from tests.test_tabular import ChainConfig, ChainMap
from vbl.engine import Experiment, Program, finish, run_experiment
from vbl.engine.jax_setup import engine_precision
from vbl.engine.nested import run_program
from vbl.engine.sweep import learner_keys
from vbl.params import param, section
from vbl.programs.tabular import make_tabular_program

F32 = jnp.float32
FINAL_STEPS = 3
CHUNKS = 4


@struct.dataclass
class ToyParams:
    rate: float = param(0.5, doc="added to x per training chunk")


@struct.dataclass
class ToyConfig:
    toy: ToyParams = section(ToyParams)


def _toy_program(cfg) -> Program:
    """x grows by ``rate`` per training chunk; each final step adds uniform(fold_in(final
    key, i)) to ``acc``; ``final`` reads both."""

    def init(key, c):
        return dict(x=jax.random.uniform(key, dtype=F32), t=jnp.int32(0), done=jnp.int32(-1),
                    key=jnp.zeros((2,), jnp.uint32), acc=jnp.float32(0.0))

    def step(carry, c):
        fin = carry["done"] >= 0
        draw = jax.random.uniform(jax.random.fold_in(carry["key"], carry["done"]), dtype=F32)
        new = dict(carry, x=jnp.where(fin, carry["x"], carry["x"] + c.toy.rate),
                   t=carry["t"] + jnp.where(fin, 0, 1), done=jnp.where(fin, carry["done"] + 1, -1),
                   acc=carry["acc"] + jnp.where(fin, draw, 0.0))
        return new, {"x": new["x"], "episodes": jnp.float32(1.0)}

    def begin_final(carry, c, key):
        return dict(carry, done=jnp.int32(0), key=key)

    def final(carry, c, key):
        return {"acc": carry["acc"], "x": carry["x"], "t": carry["t"].astype(jnp.float32),
                "done": carry["done"].astype(jnp.float32)}

    return Program(init=init, step=step, num_chunks=CHUNKS, final=final,
                   begin_final=begin_final, final_steps=FINAL_STEPS)


TOY = Experiment(name="final_steps_toy", description="toy", default_config=ToyConfig(),
                 make_program=_toy_program, seeds=3)


def _hand_final(seed_key: np.ndarray) -> float:
    key = jnp.asarray(seed_key, jnp.uint32)
    draws = [np.float32(jax.random.uniform(jax.random.fold_in(key, i), dtype=F32))
             for i in range(FINAL_STEPS)]
    return float(np.float32(sum(draws)))


def _rows(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]


def test_engine_runs_the_final_steps_between_begin_final_and_final(tmp_path):
    res = run_experiment(TOY, out=tmp_path / "run", quiet=True, plots=False)
    init_keys, final_keys = learner_keys(0, 3)
    want = [_hand_final(k) for k in final_keys]
    np.testing.assert_allclose(res.final["acc"][0], want, rtol=1e-6)
    assert len(set(np.round(want, 6))) == 3             # the seeds' final keys differ
    # the final steps train nothing and log no chunk row
    x0 = [float(jax.random.uniform(jnp.asarray(k), dtype=F32)) for k in init_keys]
    np.testing.assert_allclose(res.final["x"][0], np.asarray(x0) + CHUNKS * 0.5, rtol=1e-6)
    np.testing.assert_array_equal(res.final["t"][0], CHUNKS)
    np.testing.assert_array_equal(res.final["done"][0], FINAL_STEPS)
    rows = _rows(tmp_path / "run")
    assert [r["chunk"] for r in rows] == [*range(CHUNKS), "final"]
    np.testing.assert_allclose(res.curves["x"][0, -1], res.final["x"][0], rtol=1e-6)


def test_checkpoint_keeps_the_training_carry(tmp_path):
    """Resuming from the last chunk's checkpoint (``vbl run --resume``) runs the final
    evaluation again from the training carry: the same final row, not one that counts the
    final steps twice."""
    out = tmp_path / "run"
    first = run_experiment(TOY, out=out, quiet=True, plots=False)
    last = next(r for r in _rows(out) if r["chunk"] == "final")
    again = run_experiment(TOY, out=out, quiet=True, plots=False, resume=True)
    np.testing.assert_array_equal(again.final["acc"], first.final["acc"])
    np.testing.assert_array_equal(again.final["done"], first.final["done"])
    assert next(r for r in _rows(out) if r["chunk"] == "final") == last


def test_finish_is_the_final_in_one_traced_call():
    prog = _toy_program(ToyConfig())
    cfg = ToyConfig()
    key, fkey = jax.random.PRNGKey(3), jax.random.PRNGKey(4)

    @jax.jit
    def whole(key, fkey):
        carry = jax.lax.fori_loop(0, CHUNKS, lambda _, c: prog.step(c, cfg)[0],
                                  prog.init(key, cfg))
        return finish(prog, carry, cfg, fkey)

    got = whole(key, fkey)
    np.testing.assert_allclose(got["acc"], _hand_final(np.asarray(fkey)), rtol=1e-6)
    np.testing.assert_array_equal(got["t"], CHUNKS)
    plain = Program(init=prog.init, step=prog.step, num_chunks=1, final=prog.final)
    assert float(finish(plain, prog.init(key, cfg), cfg, fkey)["acc"]) == 0.0


def test_run_program_runs_the_final_steps_in_its_loop():
    """A program run inside another (`vbl.engine.nested.run_program`): the final metrics of
    the engine's path, and totals summed over the training chunks only."""
    prog, cfg = _toy_program(ToyConfig()), ToyConfig()
    key, fkey = jax.random.PRNGKey(3), jax.random.PRNGKey(4)
    fin, tot = jax.jit(lambda: run_program(prog, cfg, key, fkey,
                                           lambda m: {"x": m["x"], "n": m["episodes"]}))()
    np.testing.assert_allclose(fin["acc"], _hand_final(np.asarray(fkey)), rtol=1e-6)
    np.testing.assert_array_equal(fin["done"], FINAL_STEPS)
    x0 = float(jax.random.uniform(key, dtype=F32))
    np.testing.assert_allclose(tot["x"], sum(x0 + 0.5 * (i + 1) for i in range(CHUNKS)),
                               rtol=1e-6)
    np.testing.assert_array_equal(tot["n"], CHUNKS)


@pytest.mark.parametrize("kw, match", [
    (dict(final_steps=2), "needs begin_final"),
    (dict(begin_final=lambda c, cfg, k: c, final_steps=0), "final_steps >= 1"),
    (dict(begin_final=lambda c, cfg, k: c, final_steps=2, final=None), "needs final"),
])
def test_inconsistent_final_steps_are_refused(kw, match):
    base = dict(init=lambda k, c: 0, step=lambda c, cfg: (c, {}), num_chunks=1,
                final=lambda c, cfg, k: {})
    with pytest.raises(ValueError, match=match):
        Program(**{**base, **kw})


# ------------------------------------------------------------------ the tabular learner

def _units_by_evaluate(cfg, carry, fkey) -> dict:
    """Each (policy, round) unit evaluated by the runner's own ``evaluate``: the near-greedy
    and greedy policies of the learned table and the zero table, round r's starts, key
    ``split(split(fkey, 3)[policy], rounds)[r]``; (3, rounds) per statistic."""
    from vbl.agents.qlearning import make_qlearning_runner

    smap, tr = ChainMap(), cfg.train
    d = jnp.float32(tr.eval_difficulty)
    agent = cfg.agent
    if agent.lem.enabled:  # the evaluation starts (and stays) at eval_difficulty
        agent = agent.replace(lem=agent.lem.replace(initial_difficulty=d))
    run = make_qlearning_runner(smap.env, lambda o: smap.index(o, cfg), cfg.agent)
    env = cfg.env.replace(start_difficulty=d)
    q = carry.learner.q
    qs, eps = (q, q, jnp.zeros_like(q)), (0.0, tr.eval_epsilon, 0.0)
    out = {}
    for p in range(3):
        keys = jax.random.split(jax.random.split(fkey, 3)[p], tr.eval_rounds)
        for r in range(tr.eval_rounds):
            start = jax.tree.map(lambda a, r=r: a[r], carry.starts)
            s = jax.jit(run.evaluate, static_argnums=(4,))(
                keys[r], qs[p], agent, env, tr.eval_chunks * cfg.agent.chunk_steps, eps[p],
                start=start)
            for k, v in s.items():
                out.setdefault(k, np.zeros((3, tr.eval_rounds), np.float32))[p, r] = v
    return out


def _trained_and_finished(prog: Program, cfg, fkey) -> tuple:
    """(carry after ``prog.num_chunks`` training steps from key 0, that carry after
    ``begin_final`` with ``fkey`` and ``final_steps`` more steps), as the runner drives
    them."""
    step = jax.jit(lambda c: prog.step(c, cfg))
    carry = jax.jit(lambda k: prog.init(k, cfg))(jax.random.PRNGKey(0))
    for _ in range(prog.num_chunks):
        carry, _ = step(carry)
    done = jax.jit(lambda c: prog.begin_final(c, cfg, fkey))(carry)
    for _ in range(prog.final_steps):
        done, _ = step(done)
    return carry, done


@pytest.mark.parametrize("train", [
    dict(eval_every=1, eval_chunks=1),                    # a unit fills one sub-chunk
    dict(eval_every=1, eval_chunks=3),                    # units span steps (4 sub-chunks)
    dict(eval_every=2, eval_chunks=1, eval_curve=False),  # no curve: training sub-chunks
])
def test_each_final_unit_is_the_runners_evaluation(train):
    with engine_precision():       # as the engine runs programs (64-bit types on)
        _check_units(train)


def _check_units(train: dict) -> None:
    cfg = ChainConfig()
    cfg = cfg.replace(train=cfg.train.replace(num_chunks=2 * train["eval_every"], eval_rounds=3,
                                              eval_epsilon=0.3, **train),
                      agent=cfg.agent.replace(chunk_steps=10))
    prog = make_tabular_program(ChainMap(), cfg)
    subs = train["eval_every"] + (train["eval_chunks"] if train.get("eval_curve", True) else 0)
    assert prog.final_steps == -(-9 * train["eval_chunks"] // subs)
    fkey = jax.random.PRNGKey(7)
    carry, done = _trained_and_finished(prog, cfg, fkey)
    for a, b in zip(jax.tree.leaves(done.learner), jax.tree.leaves(carry.learner), strict=True):
        np.testing.assert_array_equal(a, b)              # the final steps train nothing
    want = _units_by_evaluate(cfg, carry, fkey)
    for k, v in want.items():
        np.testing.assert_array_equal(np.asarray(done.final.results[k]).reshape(3, 3), v, k)
    fin = jax.jit(lambda c: prog.final(c, cfg, fkey))(done)
    for name, (stat, p) in dict(greedy_success=("success_rate", 0),
                                near_greedy_success=("success_rate", 1),
                                random_success=("success_rate", 2),
                                greedy_primitives=("mean_primitives", 0)).items():
        np.testing.assert_allclose(fin[name], want[stat][p].mean(), rtol=1e-6, err_msg=name)
    assert 0.0 < float(fin["greedy_success"]) and float(fin["random_success"]) < 1.0
    # the engine-free path: begin_final, final_steps x step and final in one call
    one = jax.jit(lambda c: finish(prog, c, cfg, fkey))(carry)
    for k in fin:
        np.testing.assert_array_equal(one[k], fin[k], k)


# ------------------------------------------------------------------ a program inside another

@pytest.mark.slow
def test_figure5_runs_the_grids_final_through_its_own_step():
    """Figure 5's program trains the grid baseline in its step and hands on the grid's
    ``begin_final`` and ``final_steps``: its grid metrics equal ``finish`` of the grid
    program on the trained grid carry (the grid key: the second half of the final key),
    bit for bit, and the grid's evaluation episodes do not count as its training
    primitives."""
    from vbl.engine.config import apply_overrides
    from vbl.engine.registry import get
    from vbl.programs.baselines import grid_program

    exp = get("fig5_action_based")
    cfg = apply_overrides(exp.default_config, {
        **exp.quick, "eval.grid_baseline": True, "eval.episodes": 16,
        "collect.episodes_per_action": 40, "refine.iterations": 0,
        "baseline.agent.num_envs": 8, "baseline.train.num_chunks": 4,
        "baseline.train.eval_every": 2, "baseline.train.eval_rounds": 2})
    with engine_precision():
        prog = exp.make_program(cfg)
        assert prog.final_steps >= 1 and prog.num_chunks == 2
        fkey = jax.random.PRNGKey(5)
        carry, done = _trained_and_finished(prog, cfg, fkey)
        out = jax.jit(lambda c: prog.final(c, cfg, fkey))(done)
        base = cfg.baseline.on(cfg.env)
        want = jax.jit(lambda g: finish(grid_program(base), g, base,
                                        jax.random.split(fkey)[1]))(carry.grid)
    np.testing.assert_array_equal(out["grid_success"], want["greedy_success"])
    np.testing.assert_array_equal(out["random_success"], want["random_success"])
    np.testing.assert_array_equal(out["grid_primitives"], carry.grid_primitives)
    assert float(carry.grid_primitives) > 0.0
