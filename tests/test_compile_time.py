"""benchmarks/compile_time.py at a tiny size: a real program's rows, and the StableHLO
hash that marks a program a reproduce compiles once."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import compile_time as ct  # noqa: E402


def test_rows_of_one_run_and_an_identical_program_is_shared():
    from vbl.engine import registry
    from vbl.engine.reproduce import Job

    registry.discover()
    first = ct.time_run(Job("toy_bandit"))
    again = ct.time_run(Job("toy_bandit"))  # the same program, traced and compiled anew
    assert [r["function"] for r in first] == ["init", "step", "final"][:len(first)]
    assert all(r["trace_cpu_s"] > 0 and r["compile_cpu_s"] >= 0 for r in first)
    assert [r["hlo"] for r in first] == [r["hlo"] for r in again]
    assert len({r["hlo"] for r in first}) == len(first)  # init, step, final differ
    before = dict(hardware=dict(cpu="cpu", cores=2, load_average=1.0),
                  rows=[dict(first[0], trace_cpu_s=1.0, compile_cpu_s=2.0)])
    result = dict(hardware=dict(cpu="cpu", cores=2, devices=["d"], jax="x",
                                load_average=0.0), load_end=0.0, rows=first + again)
    text = ct.markdown(result, "cmd", before)
    assert [r["shared"] for r in result["rows"]] == [False] * len(first) + [True] * len(again)
    assert f"{len(first)} programs" in text and "| 3.0 |" in text


def test_quick_rows_are_the_programs_a_quick_reproduce_compiles():
    """A quick reproduce compiles Table 2's default group without the velocity control,
    no preset's program and no program of a full-run-only experiment."""
    from vbl.engine import registry

    registry.discover()
    t2, ppo = registry.get("table2_shoot_pass"), registry.get("ppo_comparator")
    assert ct.in_quick(t2, None, {"ball_velocity": False})
    assert not ct.in_quick(t2, None, {"ball_velocity": True})
    assert not ct.in_quick(t2, "monte_carlo", {"ball_velocity": False})
    assert not ct.in_quick(ppo, None, {})
    assert ct.in_quick(registry.get("grid_shooting"), None, {})


def test_quick_mode_measures_the_quick_plans():
    """``--quick`` rows come from the quick-scale plan (every row a quick program) and its
    table sums the quick run alone, or beside a quick `before` measurement."""
    from vbl.engine import registry
    from vbl.engine.reproduce import Job
    from vbl.engine.runner import resolve
    from vbl.engine.sweep import make_plan

    registry.discover()
    exp = registry.get("toy_bandit")
    sizes = {q: [g.num_learners for g in make_plan(exp, *resolve(exp, quick=q)[:3]).groups]
             for q in (False, True)}
    assert sizes[True] != sizes[False]  # the quick plan is another size
    rows = ct.time_run(Job("toy_bandit"), quick=True)
    assert rows and all(r["quick"] for r in rows)
    assert sorted({r["learners"] for r in rows}) == sorted(set(sizes[True]))
    result = dict(hardware=dict(cpu="cpu", cores=2, devices=["d"], jax="x",
                                load_average=0.0), load_end=0.0, rows=rows, quick=True)
    text = ct.markdown(result, "cmd", None)
    assert "`vbl reproduce --quick`" in text and f"{len(rows)} programs" in text
    assert "before:" not in text.split("Compiled by")[1]
    # a quick `before` (the same plans measured earlier) is compared row by row: a program
    # it lacks shows "-", and its summary counts its own programs
    old = [dict(r, trace_cpu_s=1.0, compile_cpu_s=2.0) for r in rows[:1]]
    b = dict(hardware=dict(cpu="old", cores=2, load_average=1.0), rows=old)
    text = ct.markdown(result, "cmd", b)
    table = [ln for ln in text.splitlines() if ln.startswith(f"| {rows[0]['run']} ")]
    assert table[0].split("|")[8].strip() == "3.0"
    assert all(ln.split("|")[8].strip() == "-" for ln in table[1:]) and len(table) > 1
    assert "before: 1 programs, 3 CPU s." in text and "defaults only" not in text
    assert "2-core old" in text
