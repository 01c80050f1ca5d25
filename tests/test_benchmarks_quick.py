"""Every benchmark the README's table cites runs at its ``--quick`` size through
``vbl bench --quick --out DIR`` and yields its headline figure (a finite number), so none
can rot. The committed results are left alone. Slow: each compiles real programs (10 s to
2 min each on 2 cores with a warm compilation cache, more from a cold one);
``sweep_scaling``, ``compile_time`` and ``render_throughput`` have their own tests."""

from __future__ import annotations

import math
import re

import pytest

from tests.test_cli_first_use import REPO, _tree_digest, _vbl
from vbl.engine.bench import TARGETS, headline

OWN_TESTS = {"sweep_scaling", "compile_time", "render_throughput"}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(TARGETS) - OWN_TESTS))
def test_benchmark_quick_run_gives_its_headline(name, tmp_path):
    committed = REPO / "benchmarks" / "results"
    before = _tree_digest(committed)
    r = _vbl(["bench", "--quick", "--out", str(tmp_path / "out"), name], tmp_path,
             timeout=1200)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree_digest(committed) == before
    line = headline(name, tmp_path / "out")
    assert line in r.stdout and "no figure read" not in line and "not found" not in line, line
    value = float(re.match(rf"{name}: ([-0-9.,]+)", line).group(1).replace(",", ""))
    assert math.isfinite(value) and value > 0, line
