"""tests/mutation_check.py: every mutant still applies to today's code, and one
mutant runs end to end (slow)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest

from tests.engine_helpers import REPO

_spec = importlib.util.spec_from_file_location("mutation_check",
                                               REPO / "tests" / "mutation_check.py")
mc = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mc)


@pytest.mark.parametrize("m", mc.ALL_MUTANTS, ids=lambda m: m.name)
def test_each_mutant_changes_its_file_once(m):
    text = (REPO / m.file).read_text()
    assert mc._apply(text, m) != text
    for t in m.tests:
        assert (REPO / t.split("::")[0]).is_file(), t


def test_mutant_names_are_unique_and_each_set_is_large():
    names = [m.name for m in mc.ALL_MUTANTS]
    assert len(names) == len(set(names))
    assert len(mc.ALL_MUTANTS) == sum(map(len, mc.SETS.values()))
    assert all(len(mc.SETS[k]) >= 20 for k in ("default", "--fresh", "--blind"))


@pytest.mark.slow
def test_one_mutant_is_caught_and_the_tree_is_untouched():
    before = (REPO / "vbl" / "stats.py").read_bytes()
    r = subprocess.run([sys.executable, str(REPO / "tests" / "mutation_check.py"),
                        "--only", "stats-ddof"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "score: 1/1 caught" in r.stdout
    assert (REPO / "vbl" / "stats.py").read_bytes() == before
