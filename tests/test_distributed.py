"""Multi-process start-up flags (vbl/engine/distributed.py) without starting anything: what
is refused, what is read from the environment, and what reaches jax.distributed."""

from __future__ import annotations

import pytest

from vbl.engine import distributed
from vbl.engine.errors import EngineError
from vbl.params import ParamError

ENV = ("VBL_COORDINATOR", "VBL_NUM_PROCESSES", "VBL_PROCESS_ID")


@pytest.fixture
def started(monkeypatch):
    """The (coordinator, num_processes, process_id) each start would pass to
    jax.distributed.initialize (nothing is started)."""
    calls = []
    for name in ENV:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(distributed, "_start", lambda *a: calls.append(a) or True)
    return calls


def test_a_single_process_needs_no_flags(started):
    assert distributed.initialize() is False
    assert distributed.initialize(None, 1, 0) is False
    assert started == []


@pytest.mark.parametrize("n, i", [(2, None), (None, 1), (2, 0)])
def test_process_flags_without_a_coordinator_are_refused(started, n, i):
    with pytest.raises(EngineError, match="need --coordinator"):
        distributed.initialize(None, n, i)
    assert started == []


@pytest.mark.parametrize("n, i", [(2, None), (None, 0)])
def test_a_coordinator_needs_the_count_and_the_id(started, n, i):
    with pytest.raises(EngineError, match="needs --coordinator, --num-processes and"):
        distributed.initialize("host:1234", n, i)


@pytest.mark.parametrize("n, i", [(2, 2), (2, -1), (0, 0), (3, 5)])
def test_a_process_id_outside_0_to_n_minus_1_is_refused(started, n, i):
    with pytest.raises(EngineError, match=rf"in \[0, {n - 1}\].*got {i} of {n}"):
        distributed.initialize("host:1234", n, i)
    assert started == []


def test_the_last_process_of_n_starts_with_its_flags(started):
    assert distributed.initialize("host:1234", 3, 2) is True
    assert distributed.initialize("host:1234", 1, 0) is True
    assert started == [("host:1234", 3, 2), ("host:1234", 1, 0)]


def test_the_environment_gives_what_the_flags_do_not(started, monkeypatch):
    monkeypatch.setenv("VBL_COORDINATOR", "10.0.0.1:99")
    monkeypatch.setenv("VBL_NUM_PROCESSES", "4")
    monkeypatch.setenv("VBL_PROCESS_ID", "3")
    assert distributed.initialize() is True
    assert distributed.initialize("other:1", 2, 1) is True  # flags win
    assert started == [("10.0.0.1:99", 4, 3), ("other:1", 2, 1)]
    monkeypatch.delenv("VBL_COORDINATOR")
    with pytest.raises(EngineError, match="need --coordinator"):
        distributed.initialize()


def test_coordinator_auto_leaves_detection_to_jax(started, monkeypatch):
    assert distributed.initialize("auto") is True
    assert distributed.initialize(distributed.AUTO, 2, None) is True
    assert started == [(None, None, None), (None, 2, None)]

    def no_cluster(*a):
        raise ValueError("coordinator_address should be defined")

    monkeypatch.setattr(distributed, "_start", no_cluster)
    with pytest.raises(ParamError, match="--coordinator auto: JAX detected no cluster"):
        distributed.initialize("auto")
