"""Every probe of ``benchmarks/probes`` runs at its ``--tiny`` size and prints the table it
promises (so a probe cannot rot unnoticed when the library changes under it).

The probes run in this process through their ``main(argv)`` (compiled programs come from the
suite's compilation cache), except ``env_step_ab``, whose children are processes of their
own. The numbers of a tiny run mean little: the checks are the output's shape and that its
numbers are finite and in range.
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
from pathlib import Path

import jax
import pytest

PROBES = Path(__file__).resolve().parents[1] / "benchmarks" / "probes"
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[+-]?\d+)?")
PHASES = ("shooter still", "approach", "after contact", "all rolling")


def load_probe(name: str):
    """``benchmarks/probes/<name>.py`` loaded as a fresh module."""
    spec = importlib.util.spec_from_file_location(f"probe_{name}", PROBES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def run_probe(name: str, argv: list[str], capsys) -> str:
    """Load ``benchmarks/probes/<name>.py`` as a fresh module, run ``main(argv)`` (it must
    return 0) and return what it printed."""
    mod = load_probe(name)
    capsys.readouterr()
    assert mod.main(argv) == 0
    return capsys.readouterr().out


def table(out: str, first_cell: str | None = None) -> list[list[str]]:
    """The cells of the Markdown table rows in ``out`` (header and rule skipped); with
    ``first_cell``, the rows whose first cell starts with it."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in out.splitlines() if line.startswith("|")]
    rows = [r for r in rows[1:] if not set("".join(r)) <= set("-:")]
    return [r for r in rows if first_cell is None or r[0].startswith(first_cell)]


def numbers(cell: str) -> list[float]:
    return [float(x) for x in NUMBER.findall(cell)]


def test_probe_files_all_tested():
    """A new probe needs a test here."""
    tested = {n.removeprefix("test_") for n in globals() if n.startswith("test_")}
    assert {p.stem for p in PROBES.glob("*.py")} <= tested


def test_ball_velocity_r2(capsys, tmp_path):
    out = run_probe("ball_velocity_r2", ["--tiny", "--set", "cva.n_used_objects=(6)",
                                         "--out", str(tmp_path)], capsys)
    fits, _, held = out.partition("Held out")
    rows = table(fits)
    assert [r[0].split(" (")[0] for r in rows] == ["steps used", "current", "CVA", "oracle",
                                                   "CVA, first 4", "raw history",
                                                   "history y+u"]
    assert rows[2][0] == "CVA (6)"  # the --set reached the identification
    assert all(len(r) == 5 for r in rows)  # 4 phases
    assert all(int(c) >= 18 for c in rows[0][1:])  # enough steps for a 16-regressor fit
    for r in rows[1:]:
        for cell in r[1:]:
            vals = numbers(cell)
            assert len(vals) == 2 and all(math.isfinite(v) and v <= 1.0 for v in vals), r
    assert all(min(numbers(c)) > 0.99 for c in rows[3][1:])  # the oracle holds the velocity
    # the lag's inputs and outputs hold at least what their outputs alone hold (nested fits)
    for y_only, y_u in zip(rows[5][1:], rows[6][1:], strict=True):
        assert all(b >= a - 1e-9 for a, b in zip(numbers(y_only), numbers(y_u), strict=True))
    held_rows = table(held)
    assert [r[0] for r in held_rows] == ["k-NN on history y+u", "codes of current",
                                         "codes of CVA", "codes of CVA, cancor-weighted"]
    for r in held_rows:  # held-out R^2: at most 1, negative when worse than the mean
        assert len(r) == 5
        for cell in r[1:]:
            vals = numbers(cell)
            assert len(vals) == 2 and all(math.isfinite(v) and v <= 1.0 for v in vals), r
    # --tiny writes its results file into --out only, keyed by the invocation's options
    data = json.loads((tmp_path / "ball_velocity_r2.json").read_text())
    entry = data["seed=0, envs=8, steps=40, collect_steps=600, set=cva.n_used_objects=(6)"]
    assert entry["steps_used"] == dict(zip(PHASES, map(int, rows[0][1:]), strict=True))
    assert list(entry["r2"]) == [r[0].split(" (")[0] for r in rows[1:]]
    assert [f"{v:.2f}" for v in entry["r2"]["CVA"]["approach"]] == rows[2][2].split(" / ")
    assert list(entry["held_out"]) == [r[0] for r in held_rows]
    assert entry["cpu_seconds"] > 0


def test_ball_velocity_r2_bad_set(capsys):
    """A bad override is one line and exit status 2, before any computation."""
    mod = load_probe("ball_velocity_r2")
    assert mod.main(["--tiny", "--set", "cva.no_such_path=1"]) == 2
    assert mod.main(["--tiny", "--set", "cva.n_used=0"]) == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 2 and all(line.startswith("error: ") for line in out)


def test_held_out_r2_by_hand():
    """The probe's held-out scores on hand-made data (independent: worked by hand)."""
    mod = load_probe("ball_velocity_r2")
    import numpy as np
    fit = np.array([True, True, True, True, False, False])
    y = np.array([[0.0], [2.0], [10.0], [12.0], [0.0], [12.0]])
    # code means of the fitted rows 1 and 11 predict 0 and 12: SSE 2, SST 72
    assert np.isclose(mod.code_r2(np.array([0, 0, 1, 1, 0, 1]), y, fit)[0], 1 - 2 / 72)
    # a code unseen in the fitted rows gets their mean 6: SSE 36 + 1, SST 72
    assert np.isclose(mod.code_r2(np.array([0, 0, 1, 1, 7, 1]), y, fit)[0], 1 - 37 / 72)
    # k-NN: y = x on a grid, held-out points between two grid points, k = 2 -> exact
    x = np.concatenate([np.arange(100.0), [10.5, 50.5, 80.5]])[:, None]
    f = np.arange(103) < 100
    assert np.isclose(mod.knn_r2(x, x.copy(), f, k=2)[0], 1.0)


@pytest.mark.slow  # ~40 s with a warm compilation cache: tracing 10 camera / env programs
def test_camera_ab(capsys, monkeypatch):
    # the probe switches the compilation cache off for processes it starts (it times
    # compilation); this one's cache is already set, and the variable is restored after
    monkeypatch.delenv("VBL_JAX_CACHE", raising=False)
    out = run_probe("camera_ab", ["--base", "HEAD", "--tiny"], capsys)
    rows = table(out)
    assert [r[0] for r in rows] == ["section3 camera", "section2 camera", "two-robot env step"]
    for r in rows:
        vals = [v for c in r[1:] for v in numbers(c)]
        assert len(vals) == 7 and all(math.isfinite(v) and v >= 0 for v in vals), r
    assert "Section 3 on 64 random scenes" in out and "Section 2 on the same scenes" in out


def test_env_step_ab(capsys, monkeypatch):
    cache = jax.config.jax_compilation_cache_dir
    if cache:  # the child processes compile through this process's cache
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", cache)
    out = run_probe("env_step_ab", ["--base", "HEAD", "--tiny"], capsys)
    rows = table(out)
    assert len(rows) == 1 and rows[0][:2] == ["shooting", "shared"]
    vals = [float(c) for c in rows[0][2:]]
    assert len(vals) == 3 and all(math.isfinite(v) and v > 0 for v in vals)


def test_fig5_by_start(capsys):
    out = run_probe("fig5_by_start", ["--tiny", "--refine"], capsys)
    starts = table(out, "starts")
    assert len(starts) == 1 and int(starts[0][1]) == 32
    assert sum(int(c) for c in starts[0][2:]) == 32  # every start is of one kind
    rows = table(out, "cell map") + table(out, "same map, refined")
    assert len(rows) == 2
    for r in rows:
        assert len(r) == 7
        vals = [float(c) for c in r[1:] if c != "-"]
        assert vals and all(0.0 <= v <= 1.0 for v in vals), r


def test_grid_hand_table(capsys, tmp_path):
    out = run_probe("grid_hand_table", ["--tiny", "--out", str(tmp_path)], capsys)
    found = re.findall(r"^(.*): success (\S+) \(64 starts\)$", out, re.M)
    assert [n for n, _ in found] == ["hand-written table", "random policy (all-zero table)"]
    assert all(0.0 <= float(v) <= 1.0 for _, v in found)
    data = json.loads((tmp_path / "grid_hand_table.json").read_text())
    assert list(data) == ["max_steps=30, starts=64"]
    assert [f"{v:.3f}" for v in data["max_steps=30, starts=64"]["success"].values()] == [
        v for _, v in found]


def test_grid_onestep_unlearns(capsys, tmp_path):
    out = run_probe("grid_onestep_unlearns", ["--tiny", "--out", str(tmp_path)], capsys)
    found = re.findall(r"^(.*): greedy success per chunk (.*); greedy actions changed in "
                       r"(\d+) of 319 states$", out, re.M)
    assert len(found) == 2 and found[0][0] == "one-step Q-learning"
    for _, curve, changed in found:
        vals = [float(v) for v in curve.split(", ")]
        assert len(vals) == 2 and all(0.0 <= v <= 1.0 for v in vals)  # start + 1 chunk
        assert 0 <= int(changed) <= 319
    data = json.loads((tmp_path / "grid_onestep_unlearns.json").read_text())
    learners = data["max_steps=30, chunks=1, starts=64, chunk_steps=10"]["learners"]
    assert list(learners) == [name for name, _, _ in found]
    for name, curve, changed in found:
        assert ", ".join(f"{v:.3f}" for v in learners[name]["greedy_success"]) == curve
        assert learners[name]["greedy_actions_changed"] == int(changed)


def test_lag_rule_comparison(capsys):
    out = run_probe("lag_rule_comparison", ["--tiny"], capsys)
    rows = table(out)
    assert len(rows) == 1 and rows[0][0].endswith("(default)")
    frac = numbers(rows[0][1])
    assert len(frac) == 1 and 0.0 <= frac[0] <= 100.0


def test_pixel_collection_cost(capsys):
    out = run_probe("pixel_collection_cost", ["--tiny"], capsys)
    rows = table(out)
    assert [r[0] for r in rows] == ["analytic", "pixels, noise-free", "pixels, image noise",
                                    "part: image + blob features", "part: image-noise normals"]
    for r in rows:
        vals = [v for c in r[1:] for v in numbers(c.replace(",", ""))]
        assert len(vals) == 3 and all(math.isfinite(v) and v >= 0 for v in vals), r


def test_suite_time(capsys, tmp_path):
    """The suite-time probe at toy size: cold and warm runs of one test file, their counts
    read from pytest's own closing line (the file's test count, independently collected)."""
    out = run_probe("suite_time", ["--tiny", "--out", str(tmp_path)], capsys)
    rows = table(out)
    assert [r[0] for r in rows] == ["cold", "warm"]
    data = json.loads((tmp_path / "suite_time.json").read_text())
    entry = data["tests/test_stats.py"]
    mod = load_probe("suite_time")
    tests = (PROBES.parents[1] / "tests" / "test_stats.py").read_text().count("\ndef test_")
    for phase, row in zip(("cold", "warm"), rows, strict=True):
        r = entry[phase]
        assert r["counts"]["passed"] >= tests and "failed" not in r["counts"]
        assert int(row[3]) == r["counts"]["passed"] and r["wall_s"] > 0 and r["cpu_s"] > 0
    assert entry["command"] == "python benchmarks/probes/suite_time.py --tiny"
    assert mod.counts("x\n== 3 passed, 1 failed, 2 deselected in 9.1s ==\n") == {
        "passed": 3, "failed": 1, "deselected": 2}
    assert mod.counts("no summary") == {}


@pytest.mark.parametrize("name", sorted(p.stem for p in PROBES.glob("*.py")))
def test_probe_has_tiny_option(name):
    """Every probe offers the size its test runs at."""
    assert "--tiny" in (PROBES / f"{name}.py").read_text()


@pytest.mark.slow  # 44 s: the probe's tiny run compiles the tabular program twice
def test_table2_ablation(capsys, tmp_path):
    """The ablation probe at toy size: its state map whose index ends actions runs through
    the tabular program and its results file holds per-seed rows."""
    import json

    out = tmp_path / "ablation"
    run_probe("table2_ablation", ["--tiny", "--out", str(out)], capsys)
    data = json.loads((out / "table2_ablation.json").read_text())
    rows = data["results"]["q_learning"]["index_ends_actions"]
    assert set(rows) == {"shoot, current", "shoot, cva"}
    for r in rows.values():
        assert len(r["greedy"]) == 2 and all(0.0 <= g <= 100.0 for g in r["greedy"])
        assert all(p >= 1.0 for p in r["primitives_per_decision"])  # a decision >= 1 primitive


@pytest.mark.slow  # about 3 CPU-min: a tiny vbl tune compiles the tabular program 3 times
def test_table2_tuned(capsys, tmp_path):
    """The tuning probe at toy size: one row's search, its confirmation and the defaults
    on the same fresh seeds, read into the results file with the command that reran it."""
    import json

    out = tmp_path / "tuned"
    printed = run_probe("table2_tuned", ["--tiny", "--out", str(out)], capsys)
    row = json.loads((out / "table2_tuned.json").read_text())["rows"]["shoot, current"]
    assert len(row["tuned"]) == len(row["default"]) == 2
    from vbl.engine.registry import get
    from vbl.engine.runner import resolve
    from vbl.params import get_path

    config = resolve(get("table2_shoot_pass"), quick=True)[0]
    assert row["defaults"] == {p: get_path(config, p) for p in row["best"]}
    assert 0.05 <= row["best"]["agent.learning_rate"] <= 0.8
    assert "--set env.task_pass=false" in row["command"] and "| shoot, current |" in printed


def test_table2_tuned_comparisons_against_numpy():
    """The between-row differences are Welch's: checked against a NumPy computation on
    made-up per-seed values (and a missing row leaves its comparisons out)."""
    import numpy as np

    sps = pytest.importorskip("scipy.stats")  # a peer library as the reference
    mod = load_probe("table2_tuned")
    a, b = np.array([0.2, 0.4, 0.3, 0.5]), np.array([0.1, 0.1, 0.2, 0.2])
    rows = {"pass, cva": {"default": list(a), "tuned": list(b)},
            "pass, current": {"default": list(b), "tuned": list(a)}}
    va, vb = a.var(ddof=1) / 4, b.var(ddof=1) / 4
    dof = (va + vb) ** 2 / (va**2 / 3 + vb**2 / 3)
    # Welch's dof rounded down below 30, as vbl.stats documents (a conservative interval)
    half = 100 * sps.t.ppf(0.975, np.floor(dof)) * np.sqrt(va + vb)
    lines = mod.comparisons(rows)
    assert lines[2:] == [f"| pass | CVA − current | {100 * (a - b).mean():+.1f} ± {half:.1f} | "
                         f"{100 * (b - a).mean():+.1f} ± {half:.1f} |"]


@pytest.mark.parametrize("probe", ["table2_ablation", "table2_tuned"])
def test_table2_probe_tables_are_the_committed_results(probe, capsys):
    """The findings' table between ``<!-- probe -->`` and ``<!-- /probe -->`` is what the
    probe's ``--table`` prints from its committed results file."""
    committed = run_probe(probe, ["--table"], capsys).strip()
    note = (PROBES.parents[1] / "docs" / "findings" / "table2_shoot_pass.md").read_text()
    begin, end = f"<!-- {probe} -->\n", f"\n<!-- /{probe} -->"
    assert note[note.index(begin) + len(begin):note.index(end)] == committed, (
        f"docs/findings/table2_shoot_pass.md: the {probe} table differs from "
        f"`python benchmarks/probes/{probe}.py --table`")


def test_table2_ablation_whitening():
    """The whiten variant's transform against NumPy: within each block the whitened states
    have the identity covariance (correlated, unequally scaled components), the blocks stay
    apart (no cross-block mixing), and a zero-padded component stays 0 (no NaN)."""
    import numpy as np

    mod = load_probe("table2_ablation")
    rng = np.random.default_rng(0)
    a = rng.normal(size=(4000, 3)) @ np.array([[3.0, 0, 0], [2.0, 0.5, 0], [0, 1.0, 0.1]])
    b = rng.normal(size=(4000, 2)) * [10.0, 0.01] + [5.0, -1.0]
    x = np.concatenate([a, b, np.zeros((4000, 1))], axis=1).astype(np.float32)
    mean, w = (np.asarray(v, np.float64) for v in mod.whitening(x, (3, 2, 1)))
    z = (x - mean) @ w
    for lo, hi in ((0, 3), (3, 5)):
        np.testing.assert_allclose(np.cov(z[:, lo:hi].T, bias=True), np.eye(hi - lo),
                                   atol=2e-3)
    assert np.all(w[:3, 3:] == 0) and np.all(w[3:, :3] == 0)
    assert np.all(np.isfinite(z)) and np.all(z[:, 5] == 0)


@pytest.mark.slow
def test_table2_ablation_whiten_tiny(capsys, tmp_path):
    """The whiten variant's state map runs through the tabular program at toy size."""
    import json

    out = tmp_path / "ablation"
    run_probe("table2_ablation", ["--tiny", "--variants", "whiten", "--out", str(out)], capsys)
    rows = json.loads((out / "table2_ablation.json").read_text())["results"]["q_learning"]
    assert set(rows["whiten"]) == {"shoot, current", "shoot, cva"}
