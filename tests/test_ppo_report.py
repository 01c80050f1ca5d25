"""The PPO comparator's report (vbl.programs.ppo_report) on a synthetic run: every row of the
two-robot sweep gets its cells, and the verdicts follow hand-computed Welch intervals."""

import re
from pathlib import Path

import numpy as np

from vbl.engine.experiment import RunResult
from vbl.programs.paper import TABLE2
from vbl.programs.ppo_report import diff_verdict, shoot_pass_section


def test_diff_verdict_matches_a_hand_computed_welch_interval():
    """a = (1, 2, 3), b = (0, 0, 1): d = 5/3; variances of the means 1/3 and 1/9, Welch's
    dof = (4/9)^2 / ((1/3)^2/2 + (1/9)^2/2) = 3.2 -> t(3) = 3.182446 (table, rounded down);
    half-width 3.182446 * sqrt(4/9) = 2.1216."""
    assert diff_verdict([1, 2, 3], [0, 0, 1]) == ("+1.7 ± 2.1 (spans 0: not resolved at 3 "
                                                  "seeds, about 6 would resolve it)")
    assert diff_verdict([10, 11, 12], [0, 0, 1], paper=5.0) == (
        "+10.7 ± 2.1 (above 0; paper's +5.0 below it)")
    assert diff_verdict([0.5], [0.1, 0.2]).endswith("(one seed: no interval)")


def _two_robot_run(tmp_path: Path, pct: dict) -> RunResult:
    """A finished ppo_comparator run: 12 points (task x input x curriculum), 3 seeds,
    greedy success rates pct[(task_pass, index, curriculum)] (3,) in %."""
    from types import SimpleNamespace

    points = [{"env.task_pass": tp, "inputs.index": i, "ppo.curriculum.enabled": c}
              for tp in (False, True) for i in (0, 1, 2) for c in (False, True)]
    final = np.array([np.asarray(pct[p["env.task_pass"], p["inputs.index"],
                                     p["ppo.curriculum.enabled"]]) / 100 for p in points])
    chunks = 2
    curves = {"env_steps": np.broadcast_to(np.array([1280.0, 2560.0])[None, :, None],
                                           (12, chunks, 3)).copy(),
              "success_rate": np.full((12, chunks, 3), 0.5)}
    cfg = SimpleNamespace(env=SimpleNamespace(task_pass=False),
                          inputs=SimpleNamespace(index=0),
                          ppo=SimpleNamespace(curriculum=SimpleNamespace(enabled=False)))
    return RunResult("ppo_comparator", tmp_path, cfg, {}, points, 3, curves,
                     {"greedy_success_rate": final}, {})


def test_two_robot_report_gives_every_row_its_cells(tmp_path):
    base = {(tp, i, c): [40.0, 50.0, 60.0] for tp in (False, True) for i in (0, 1, 2)
            for c in (False, True)}
    base[True, 2, False] = [90.0, 91.0, 92.0]  # pass, CVA, no curriculum: far above current
    base[True, 0, False] = [10.0, 11.0, 12.0]
    base[False, 1, True] = [0.0, 50.0, 100.0]  # shoot, stack, curriculum: a wide interval
    md = shoot_pass_section(_two_robot_run(tmp_path, base), TABLE2).markdown
    assert (tmp_path / "ppo_success_vs_steps.png").is_file()
    table = [r for r in md.splitlines() if re.match(r"\| (shoot|pass) \| (current|stack|cva) \|",
                                                   r)]
    assert len(table) == 6  # one row per task x input, both curriculum settings as columns
    for row in table:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert len(cells) == 6 and all(cells), row
        assert re.fullmatch(r"\d+\.\d ± \d+\.\d", cells[2]), row  # curriculum off
        assert re.fullmatch(r"\d+\.\d ± \d+\.\d", cells[3]) or (  # curriculum on
            cells[:2] == ["shoot", "stack"]  # 0, 50, 100 %: a t interval beyond [0, 100]
            and cells[3] == "50.0 (3 seeds: too few for an interval)"), row
    rows = {tuple(c.strip() for c in r.strip("|").split("|")[:2]): r for r in md.splitlines()
            if re.match(r"\| (shoot|pass) \| (off|on) \|", r)}
    assert set(rows) == {(t, c) for t in ("shoot", "pass") for c in ("off", "on")}
    # pass, off: CVA 91 vs current 11: +80, Welch dof 4, 2.776445 * sqrt(2/3) = 2.27
    assert "+80.0 ± 2.3 (above 0; paper's +43.4 below it)" in rows["pass", "off"]
    assert "CVA: yes, larger than the paper's" in rows["pass", "off"]
    # vs the paper's 53.2 %: stack 50 ± 4.302653 * 10 / sqrt(3) = 50 ± 24.8 holds it
    assert "current below; stack inside; cva above" in rows["pass", "off"]
    # shoot, on: CVA equal to current, 0 ± 22.7 (2.776445 * sqrt(200/3)), below +68.3;
    # stack 0 ± 126.7 (Welch, dof 2.2) holds it
    assert "CVA: no, none of the paper's size; stack: not resolved" in rows["shoot", "on"]


def test_two_robot_report_with_one_seed_prints_means_only(tmp_path):
    run = _two_robot_run(tmp_path, {(tp, i, c): [50.0, 50.0, 50.0] for tp in (False, True)
                                    for i in (0, 1, 2) for c in (False, True)})
    run.final["greedy_success_rate"] = run.final["greedy_success_rate"][:, :1]
    run.curves = {k: v[:, :, :1] for k, v in run.curves.items()}
    run.seeds = 1
    md = shoot_pass_section(run, TABLE2).markdown
    assert "nan" not in md.lower()
    assert "| shoot | current | 50.0 | 50.0 |" in md
    assert "no interval" in md


def test_diff_verdict_of_constant_samples_is_exact():
    assert diff_verdict([2.0, 2.0], [2.0, 2.0]) == "+0.0 ± 0.0 (spans 0)"
    assert diff_verdict([3.0, 3.0], [2.0, 2.0]) == "+1.0 ± 0.0 (above 0)"


def test_ppo_agents_do_not_import_the_engine():
    """Layers: the PPO learner (vbl/agents/ppo*.py) sits below the engine; its programs and
    report (vbl/engine/ppo_*.py) import it, never the other way round."""
    import ast

    root = Path(__file__).resolve().parents[1] / "vbl" / "agents"
    files = sorted(root.glob("ppo*.py"))
    assert len(files) >= 3
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for n in names:
                assert not n.startswith(("vbl.engine", "vbl.cli")), f"{f.name} imports {n}"
