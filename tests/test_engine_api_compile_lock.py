"""Processes sharing the compilation cache compile a program once: the lock around a
compilation (``vbl.engine.jax_setup.program_lock`` / ``compile_shared``) makes a second
compiler of the same program wait for the first, then read the cache. ``flock`` locks of
two opens of one file exclude each other also within one process, so threads stand in for
the processes here; the cache's own reads are checked across real processes."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import jax
import jax.numpy as jnp

from vbl.engine import jax_setup
from vbl.engine.jax_setup import LOCKS_DIR, compile_shared, program_lock

# A program that compiles in milliseconds; prints how often the process read the
# persistent cache and how often it found the program there.
_SMALL_PROGRAM = """
import jax, jax.numpy as jnp
from jax import monitoring
from vbl.engine.jax_setup import use_compilation_cache
use_compilation_cache()
seen = []
monitoring.register_event_listener(lambda name, **kw: seen.append(name))
jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.0)(jnp.arange(5.0)).block_until_ready()
print(seen.count("/jax/compilation_cache/compile_requests_use_cache"),
      seen.count("/jax/compilation_cache/cache_hits"))
"""


def _hold(path, seconds: float, started: threading.Event) -> threading.Thread:
    def run():
        with program_lock(path) as held:
            assert held
            started.set()
            time.sleep(seconds)

    t = threading.Thread(target=run)
    t.start()
    assert started.wait(10)
    return t


def test_the_lock_waits_for_its_holder_then_is_taken(tmp_path):
    path = tmp_path / "locks" / "k.lock"  # its folder is made
    t = _hold(path, 0.6, threading.Event())
    t0 = time.monotonic()
    with program_lock(path, poll_s=0.02) as held:
        waited = time.monotonic() - t0
        assert held
    t.join()
    assert waited >= 0.3, waited


def test_a_lock_that_stays_taken_or_cannot_be_made_runs_the_block_unlocked(tmp_path):
    path = tmp_path / "k.lock"
    t = _hold(path, 1.0, threading.Event())
    with program_lock(path, wait_s=0.1, poll_s=0.02) as held:
        assert held is False
    t.join()
    (tmp_path / "file").write_text("")
    with program_lock(tmp_path / "file" / "k.lock") as held:  # no folder can be made
        assert held is False


def test_compile_shared_compiles_under_the_programs_lock(tmp_path, monkeypatch):
    monkeypatch.setattr(jax_setup, "shared_cache_folder", lambda: str(tmp_path))
    f = jax.jit(lambda x: jnp.sin(x) * 3.0)
    x = jnp.ones(7)
    compile_shared(f, x)
    locks = list((tmp_path / LOCKS_DIR).glob("*.lock"))
    assert len(locks) == 1  # one program, one lock file named by its hash
    # the same program compiled while another holds its lock waits for it
    g = jax.jit(lambda x: jnp.sin(x) * 3.0)
    t = _hold(locks[0], 0.6, threading.Event())
    t0 = time.monotonic()
    compile_shared(g, x)
    assert time.monotonic() - t0 >= 0.3
    t.join()
    assert g(x).tolist() == f(x).tolist()
    compile_shared(jax.jit(lambda x: x + 1.0), x)  # another program: another lock
    assert len(list((tmp_path / LOCKS_DIR).glob("*.lock"))) == 2


def test_without_the_cache_nothing_is_locked(tmp_path, monkeypatch):
    monkeypatch.setattr(jax_setup, "shared_cache_folder", lambda: None)
    calls = []
    monkeypatch.setattr(jax_setup, "program_lock", lambda *a, **k: calls.append(a))
    compile_shared(jax.jit(lambda x: x * 2.0), jnp.ones(3))
    assert calls == []


def test_each_kind_of_cpu_has_its_own_cache_folder(monkeypatch, tmp_path):
    """Programs compiled for one CPU's instruction set are never read on another: the cache
    folder is keyed by the CPU's feature flags (in any order), and off means no folder."""
    from vbl.engine.jax_setup import _cache_dir, machine_key

    avx = "processor : 0\nflags : fpu sse2 avx2 avx512f\n"
    assert machine_key(avx) == machine_key("flags\t: avx512f avx2 fpu sse2\n")
    assert machine_key(avx) != machine_key("processor : 0\nflags : fpu sse2 avx2\n")
    monkeypatch.setenv("VBL_JAX_CACHE", str(tmp_path))
    assert _cache_dir() == str(tmp_path / machine_key())
    monkeypatch.setenv("VBL_JAX_CACHE", "0")
    assert _cache_dir() is None


def test_a_program_of_milliseconds_is_read_back_by_the_next_process(tmp_path):
    """Every program is cached, however fast it compiles (JAX's default leaves out those
    under a second, which a warm run would compile again): the second process finds it."""
    env = dict(os.environ, VBL_JAX_CACHE=str(tmp_path), JAX_PLATFORMS="cpu")
    counts = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _SMALL_PROGRAM], env=env, text=True,
                             capture_output=True, timeout=120, check=True).stdout
        counts.append(tuple(int(n) for n in out.split()))
    (asked, found), (asked_again, found_again) = counts
    assert asked >= 1 and found == 0  # a fresh cache
    assert found_again == asked_again == asked  # the next process compiles nothing
