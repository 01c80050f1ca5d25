"""The trace cache (``vbl.engine.trace_cache``): a program whose code, config and arguments
are unchanged is read back, not traced; any change traces it again; an unreadable file is
traced again and rewritten; concurrent writers leave a whole file."""

from __future__ import annotations

import subprocess
import sys
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.engine_helpers import TINY_SETS, toy_experiment
from vbl.engine import jax_setup, trace_cache
from vbl.engine.runner import _per_device, run_experiment
from vbl.engine.sharding import learner_sharding, put
from vbl.engine.sweep import make_plan


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The trace cache on in ``tmp_path``; ``new_process()`` forgets what this process
    loaded, as a new process would."""
    monkeypatch.setattr(jax_setup, "shared_cache_folder", lambda: str(tmp_path))
    monkeypatch.setitem(trace_cache._STATE, "on", True)
    monkeypatch.setattr(trace_cache, "_LOADED", {})
    return tmp_path / trace_cache.TRACES_DIR


def _program(traces: list):
    """A per-device program (as the engine builds them) that counts its traces."""
    def step(carry, cfg):
        traces.append(1)
        return {"x": carry["x"] * cfg + 1.0}, carry["x"].sum()

    sharding = learner_sharding()
    n = len(sharding.mesh.devices.flat)
    args = (put({"x": np.arange(3.0 * n).reshape(n, 3)}, sharding),
            put(np.full(n, 2.0), sharding))
    return _per_device(step, sharding), args


def _same(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b),
                                                      strict=True))


def test_a_warm_call_does_not_trace_and_gives_the_same_result(cache, monkeypatch):
    traces = []
    fn, args = _program(traces)
    want = fn(*args)
    cold = trace_cache.traced(fn, "prog cfg", *args)
    assert cold is not fn and len(list(cache.glob("*.jaxexport"))) == 1
    n = len(traces)
    assert _same(cold(*args), want)
    monkeypatch.setattr(trace_cache, "_LOADED", {})  # a new process
    warm = trace_cache.traced(fn, "prog cfg", *args)
    assert _same(warm(*args), want)
    assert len(traces) == n  # read back: the program was not traced


def test_changed_code_config_or_arguments_trace_again(cache, monkeypatch):
    traces = []
    fn, args = _program(traces)
    trace_cache.traced(fn, "prog cfg", *args)
    n = len(traces)
    trace_cache.traced(fn, "prog cfg2", *args)  # another config
    assert len(traces) == n + 1
    wider = jax.tree.map(lambda x: jnp.concatenate([x, x]), args)  # other shapes
    trace_cache.traced(fn, "prog cfg", *wider)
    assert len(traces) == n + 2
    monkeypatch.setattr(trace_cache, "code_key", lambda folder=None: "changed")
    trace_cache.traced(fn, "prog cfg", *args)  # another source hash
    assert len(traces) == n + 3
    assert len(list(cache.glob("*.jaxexport"))) == 4


def test_the_source_hash_follows_the_files(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    before = trace_cache.code_key(tmp_path)
    (tmp_path / "a.py").write_text("x = 2\n")
    trace_cache.code_key.cache_clear()
    assert trace_cache.code_key(tmp_path) != before


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_an_unreadable_file_is_traced_again_and_rewritten(cache, monkeypatch, damage):
    traces = []
    fn, args = _program(traces)
    want = fn(*args)
    trace_cache.traced(fn, "prog cfg", *args)
    (path,) = cache.glob("*.jaxexport")
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"\x00junk\n" * 9,
                      "empty": b""}[damage])
    monkeypatch.setattr(trace_cache, "_LOADED", {})
    n = len(traces)
    again = trace_cache.traced(fn, "prog cfg", *args)
    assert len(traces) == n + 1 and _same(again(*args), want)
    assert trace_cache._read(path) is not None  # rewritten whole


def test_a_program_whose_output_class_is_not_importable_runs_and_is_not_written(cache):
    """A script imported outside ``sys.modules`` (``spec.loader.exec_module`` alone) has
    classes that no reader could find by name: the program runs, and no file is left
    that every later run would fail to read."""
    class Out:
        def __init__(self, x):
            self.x = x

    Out.__module__ = "_not_in_sys_modules"
    jax.tree_util.register_pytree_node(Out, lambda o: ((o.x,), None), lambda _, c: Out(*c))
    assert Out.__module__ not in sys.modules
    fn = jax.jit(lambda x: Out(x * 2.0))
    x = jnp.arange(3.0)
    got = trace_cache.traced(fn, "out cfg", x)(x)
    assert isinstance(got, Out) and np.array_equal(got.x, [0.0, 2.0, 4.0])
    assert not list(cache.glob("*.jaxexport*"))


def test_concurrent_writers_leave_a_whole_file(cache):
    traces = []
    fn, args = _program(traces)
    trace_cache.traced(fn, "prog cfg", *args)
    (path,) = cache.glob("*.jaxexport")
    exported, skeleton = trace_cache._read(path)
    bad, stop = [], threading.Event()

    def write():
        for _ in range(20):
            trace_cache._write(path, exported, skeleton)

    def read():
        while not stop.is_set():
            if trace_cache._read(path) is None:
                bad.append(1)

    writers = [threading.Thread(target=write) for _ in range(2)]
    reader = threading.Thread(target=read)
    reader.start()
    for t in writers:
        t.start()
    for t in writers:
        t.join()
    stop.set()
    reader.join()
    assert not bad
    assert [p.name for p in cache.iterdir()] == [path.name]  # no temporary file is left


def test_off_unless_the_command_turns_it_on(tmp_path, monkeypatch):
    monkeypatch.setattr(jax_setup, "shared_cache_folder", lambda: str(tmp_path))
    monkeypatch.setitem(trace_cache._STATE, "on", False)
    fn, args = _program([])
    assert trace_cache.traced(fn, "prog cfg", *args) is fn
    monkeypatch.setenv("VBL_TRACE_CACHE", "0")
    trace_cache.use_trace_cache()
    assert trace_cache.traced(fn, "prog cfg", *args) is fn


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("toy"))


def test_a_run_reads_its_programs_back_with_the_same_results(cache, toy, tmp_path,
                                                             monkeypatch):
    exports = []
    real = trace_cache._export
    monkeypatch.setattr(trace_cache, "_export", lambda *a: exports.append(1) or real(*a))

    def run(name: str) -> bytes:
        run_experiment(toy, sets=TINY_SETS, seeds=2, out=tmp_path / name, quiet=True,
                       plots=False, report=False)
        return (tmp_path / name / "metrics.jsonl").read_bytes()

    with monkeypatch.context() as m:
        m.setitem(trace_cache._STATE, "on", False)
        off = run("off")
    assert not exports
    cold = run("cold")
    n = len(exports)
    assert n >= 2 and len(list(cache.glob("*.jaxexport"))) == n  # init, step (, final)
    monkeypatch.setattr(trace_cache, "_LOADED", {})  # a new process
    warm = run("warm")
    assert len(exports) == n  # every program read back
    assert off == cold == warm


LINALG = """
import sys
import jax, jax.numpy as jnp, numpy as np
from vbl.engine import jax_setup, trace_cache
jax_setup.shared_cache_folder = lambda: sys.argv[1]
trace_cache._STATE["on"] = True
with jax.enable_x64(True):
    f = jax.jit(lambda a: jnp.linalg.cholesky(a @ a.T + 3.0 * jnp.eye(4)))
    x = jnp.asarray(np.arange(16.0).reshape(4, 4) / 10)
    print(np.asarray(trace_cache.traced(f, "chol", x)(x)).tobytes().hex())
"""


def test_a_linear_algebra_program_read_back_in_a_new_process_runs(tmp_path):
    """XLA's CPU LAPACK kernels need LAPACK loaded, which JAX does when it lowers them:
    a process that reads the program back and lowers nothing loads it too (without,
    the call crashes the process)."""
    runs = [subprocess.run([sys.executable, "-c", LINALG, str(tmp_path)], capture_output=True,
                           text=True, timeout=300) for _ in range(2)]  # cold, then warm
    assert [r.returncode for r in runs] == [0, 0], runs[1].stderr[-2000:]
    assert runs[0].stdout == runs[1].stdout


def _counting_toy(toy, monkeypatch, traces: list):
    """``toy`` (the toy experiment), its ``init`` counting its traces, keyed in the trace
    cache as the toy script's."""
    import dataclasses

    from vbl.engine import runner
    from vbl.engine.experiment import Experiment

    def make_program(cfg):
        prog = toy.make_program(cfg)

        def init(key, c):
            traces.append(1)
            return prog.init(key, c)
        return dataclasses.replace(prog, init=init)

    exp = Experiment(name="counting_toy", description="the toy, counting init traces",
                     default_config=toy.default_config, make_program=make_program)
    real = runner.source_file
    monkeypatch.setattr(runner, "source_file",
                        lambda name: real("toy_bandit" if name == "counting_toy" else name))
    return exp


def test_a_run_traces_init_once_for_its_memory_check_and_its_run(cache, toy, tmp_path,
                                                                  monkeypatch):
    """The memory check sizes a learner's state from the per-device init the run calls:
    a cold run traces each group's init once (not once to check and once to run), a warm
    run (a new process) not at all, and the estimate is the same either way."""
    from vbl.engine import memory, runner

    traces, estimates, plans = [], [], []
    real = memory.estimate

    def recording(plan, state_bytes=memory.carry_bytes):
        plans.append(plan)
        estimates.append(real(plan, state_bytes))
        return estimates[-1]

    monkeypatch.setattr(memory, "estimate", recording)
    exp = _counting_toy(toy, monkeypatch, traces)
    args = dict(sets={"train.pulls_per_chunk": 5}, sweep={"env.num_arms": [3, 4]}, seeds=2,
                quiet=True)
    run_experiment(exp, out=tmp_path / "cold", **args)
    assert len(traces) == 2  # the toy's two groups (num_arms is static)
    monkeypatch.setattr(trace_cache, "_LOADED", {})  # a new process
    runner._JITTED.clear()
    run_experiment(exp, out=tmp_path / "warm", **args)
    assert len(traces) == 2
    assert estimates[0] == estimates[1] and estimates[0][1]["carry_bytes"] > 0
    # the same as one learner's init traced alone
    assert estimates[0] == real(plans[0])


def test_a_script_imported_under_another_module_name_traces_its_own_programs(
        cache, toy, tmp_path, monkeypatch):
    """The same script imported from another path is another module, with other classes:
    its run does not read back the first module's programs. Here the cache holds only the
    first module's ``init`` (its memory check ran, its run did not): read back, its
    carries would be of the first module's classes, and the step traced from the second
    module's code would not take them."""
    from tests.engine_helpers import TOY
    from vbl.engine import registry, runner

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    with monkeypatch.context() as m:  # the toy in the built-in experiments folder
        m.delenv("VBL_EXPERIMENTS_DIR")
        builtin = registry.load_script(TOY).EXPERIMENT
    assert type(builtin.default_config).__module__ != type(toy.default_config).__module__
    sets = {**TINY_SETS, "train.num_chunks": 2}
    with jax_setup.engine_precision():
        config, sweep, seeds, _ = runner.resolve(builtin, sets, None, 2)
        plan = make_plan(builtin, config, sweep, seeds)
        runner._state_bytes(builtin, learner_sharding(), runner.DEFAULT_LEARNER_BATCH)(
            plan.groups[0])
    assert len(list(cache.glob("*.jaxexport"))) == 1  # the first module's init
    monkeypatch.setattr(trace_cache, "_LOADED", {})  # a new process
    runner._JITTED.clear()
    result = run_experiment(toy, sets=sets, seeds=2, out=tmp_path / "b", quiet=True)
    assert result.final


def test_an_experiment_registered_from_no_script_is_not_cached(cache, toy, tmp_path):
    """Its programs have no ident (no script's code in the key): two such experiments of
    the same shapes would share files, so neither its memory check nor its run writes
    one."""
    import dataclasses

    exp = dataclasses.replace(toy, name="scriptless_toy")
    run_experiment(exp, sets={**TINY_SETS, "train.num_chunks": 2}, seeds=2,
                   out=tmp_path / "r", quiet=True)
    assert not list(cache.glob("*.jaxexport"))
