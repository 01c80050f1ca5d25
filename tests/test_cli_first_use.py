"""A new user's first hour: the README's own-experiment script run as written, `vbl run
path/to/script.py` importing nothing else, the report and a short table from `vbl run`,
`--sweep` announcing the points it runs, and `vbl bench --out` leaving the committed
results alone."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.engine_helpers import REPO

TIMEOUT = 300  # s per subprocess (the test machine is shared)


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ, CI="true", VBL_HOST_DEVICES="1")
    for k in ("VBL_EXPERIMENTS_DIR", "XLA_FLAGS"):
        env.pop(k, None)
    env.update(extra)
    return env


def _vbl(args: list[str], cwd: Path, timeout: float = TIMEOUT,
         **extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vbl.cli", *args], cwd=cwd, env=_env(**extra),
                          capture_output=True, text=True, timeout=timeout)


def doc_scripts(section: str) -> list[str]:
    """The Python blocks of a section of docs/engine.md, exactly."""
    text = (REPO / "docs" / "engine.md").read_text()
    m = re.search(rf"^## {section}\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, f"docs/engine.md has no '## {section}' section"
    return re.findall(r"^```python\n(.*?)^```", m.group(1), re.S | re.M)


def readme_script() -> str:
    """The Python block of docs/engine.md's "Your own experiment" section."""
    blocks = doc_scripts("Your own experiment")
    assert len(blocks) == 1, "the section holds one python block"
    return blocks[0]


def test_the_reuse_examples_load_and_resolve(tmp_path):
    """The scripts of "Reusing the paper's learners" register experiments whose configs
    are the paper learners' with the changes they state."""
    from vbl.engine.registry import load_experiment_file
    from vbl.engine.runner import resolve

    grid, cva = doc_scripts("Reusing the paper's learners")
    for name, text in (("grid_big_ball", grid), ("pass_step_sizes", cva)):
        (tmp_path / f"{name}.py").write_text(text)
        exp = load_experiment_file(str(tmp_path / f"{name}.py"))
        assert exp.name == name and exp.make_program is not None
        config, sweep, seeds, _ = resolve(exp)
        assert seeds >= 8 and len(next(iter(sweep.values()))) >= 2
    assert config.task == "pass" and config.agent.learning_rate == 0.25


def test_readme_experiment_runs_from_a_temporary_folder(tmp_path):
    script = readme_script()
    assert 25 <= len(script.splitlines()) <= 40
    (tmp_path / "two_arms.py").write_text(script)
    # a helper beside it must not be imported by `vbl run two_arms.py`
    (tmp_path / "helper.py").write_text("open('HELPER_RAN', 'w').close()\n")
    r = _vbl(["run", "two_arms.py", "--out", "run"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert not (tmp_path / "HELPER_RAN").exists()
    assert "two_arms: 3 sweep points x 16 seeds = 48 learners" in r.stdout
    assert "greedy_success" in r.stdout and "±" in r.stdout
    assert max(len(line) for line in r.stdout.splitlines()) <= 100
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert len(summary["points"]) == 3
    report = (run / "report.md").read_text()
    assert "greedy_success" in report and "![train_success](train_success.png)" in report
    marker = json.loads((run / ".vbl-run").read_text())
    assert "report.md" in marker["files"]
    r = _vbl(["params", "two_arms.py"], tmp_path)
    assert r.returncode == 0 and "| `epsilon` |" in r.stdout, r.stderr[-3000:]
    r = _vbl(["list"], tmp_path)  # the built-in experiments, not the folder's scripts
    assert r.returncode == 0 and "grid_shooting" in r.stdout and "two_arms" not in r.stdout
    assert not (tmp_path / "HELPER_RAN").exists()


EXPERIMENT_WITH_REPORT = '''
from pathlib import Path
import sys
sys.path.insert(0, {repo!r})
from experiments.toy_bandit import BanditConfig, make_program  # noqa: E402
from vbl.engine import Experiment, ReportSection, register  # noqa: E402


def report(res):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.plot(res.final["greedy_is_best"].mean(axis=1))
    path = Path(res.out_dir) / "own_figure.png"
    fig.savefig(path)
    return ReportSection("own report: " + str(len(res.points)) + " points", (path,))


register(Experiment(name="with_report", description="toy with its own report",
                    default_config=BanditConfig(), make_program=make_program, report=report,
                    seeds=2, quick={{"train.num_chunks": 2}},
                    headline=("greedy_is_best",)))
'''


def test_run_writes_the_experiments_report_and_a_short_table(tmp_path):
    (tmp_path / "exp.py").write_text(EXPERIMENT_WITH_REPORT.format(repo=str(REPO)))
    r = _vbl(["run", str(tmp_path / "exp.py"), "--quick", "--set", "env.num_arms=3",
              "--sweep", "agent.epsilon=0.1,0.2", "--out", str(tmp_path / "run")], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    run = tmp_path / "run"
    report = (run / "report.md").read_text()
    assert "own report: 2 points" in report and "![own_figure](own_figure.png)" in report
    assert "own_figure.png" in json.loads((run / ".vbl-run").read_text())["files"]
    table = r.stdout.split("learners\n", 1)[1]
    assert "greedy_is_best" in table and "regret" not in table  # the headline only


@pytest.mark.parametrize("script, message, code", [
    ("missing.py", "no experiment script", 2),  # bad input
    ("empty.py", "registers no experiment", 1),
    ("broken.py", "failed to import: ZeroDivisionError", 1),
])
def test_run_script_errors_are_one_line(tmp_path, script, message, code):
    (tmp_path / "empty.py").write_text("x = 1\n")
    (tmp_path / "broken.py").write_text("1 / 0\n")
    r = _vbl(["run", script], tmp_path)
    assert r.returncode == code
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vbl: error:") and message in lines[0], \
        r.stderr


def test_headline_table_fits_100_columns():
    from vbl.engine.experiment import RunResult
    from vbl.engine.report import headline_table

    st = {"mean": 0.123456, "std": 0.1, "ci95": 0.0456}
    points = [{"values": {"agent.lem.initial_difficulty": v},
               "final": {f"final_metric_{i}": st for i in range(6)},
               "last_chunk": {f"chunk_metric_{i}": st for i in range(11)}} for v in (1.0, 0.0)]
    res = RunResult("x", Path("."), None, {}, [{}, {}], 4, {}, {}, {"points": points,
                                                                     "seeds": 4})
    text = headline_table(res)
    assert max(map(len, text.splitlines())) <= 100
    assert "0.123 ± 0.046" in text and "more metrics in summary.json" in text
    assert len(text.splitlines()) == 2 + 2 + 1


def test_headline_table_keeps_a_rates_interval_in_its_range():
    """The terminal shows the reports' statistic: a success rate's interval stays in
    [0, 1] (clipped, or 'too few' under 4 seeds); another metric's is the t interval."""
    from vbl.engine.experiment import RunResult
    from vbl.engine.report import headline_table
    from vbl.stats import mean_ci95

    def stat(x):
        m, h = mean_ci95(x)
        return {"mean": m, "std": 0.0, "ci95": h, "per_seed": x}

    table = {}
    for seeds in ([0.0, 0.5], [0.0, 0.0, 0.05, 0.6, 0.0, 0.0]):
        points = [{"values": {}, "final": {"greedy_success": stat(seeds),
                                           "td_abs": stat([-v for v in seeds])}}]
        res = RunResult("x", Path("."), None, {}, [{}], len(seeds), {}, {},
                        {"points": points, "seeds": len(seeds)})
        table[len(seeds)] = headline_table(res)
    assert "0.25 (2 seeds: too few for an interval)" in table[2]
    m, h = mean_ci95([0.0, 0.0, 0.05, 0.6, 0.0, 0.0])
    assert m - h < 0 and f"0.108 [0, {m + h:.3g}]" in table[6]  # clipped at 0
    assert f"-0.108 ± {h:.3g}" in table[6]  # not a rate: the t interval


def test_one_unit_per_metric_in_the_terminal_and_the_report():
    """An experiment whose paper gives a result in % (Table 2, PPO) shows its success rates
    in % in the terminal table and the default report (heading marked), other metrics as
    they are; one that does not keeps fractions. The README's rows agree: Table 2's are in
    %, the grid baseline's in fractions."""
    from vbl.engine.experiment import RunResult
    from vbl.engine.registry import get
    from vbl.engine.report import default_section, headline_table

    x = [0.25, 0.5, 0.75, 0.5]  # mean 0.5, sd 0.2041: t(0.975, 3) 3.182 x sd / 2 = 0.3249
    st = {"mean": 0.5, "std": 0.0, "ci95": 0.3249, "per_seed": x}
    points = [{"values": {}, "final": {"greedy_success": st, "greedy_primitives": st}}]
    res = RunResult("x", Path("."), None, {}, [{}], 4, {}, {}, {"points": points, "seeds": 4})
    table2, grid = get("table2_shoot_pass"), get("grid_shooting")
    assert table2.percent and get("ppo_comparator").percent and not grid.percent
    in_pct, as_rate = headline_table(res, table2), headline_table(res, grid)
    assert "greedy_success %" in in_pct and "50.0 ± 32.5" in in_pct
    assert "0.5 ± 0.325" in in_pct  # greedy_primitives: not a rate, as it is
    assert "greedy_success %" not in as_rate and "50.0" not in as_rate
    report = default_section(res, percent=True).markdown
    assert "greedy_success % (final)" in report and "50.0 ± 32.5" in report
    readme = (REPO / "README.md").read_text()
    assert "Table 2, shooting, current features: greedy success %" in readme
    assert "Grid baseline (319 states), with LEM: greedy / near-greedy success |" in readme


@pytest.fixture(scope="module")
def grid_shooting():
    from vbl.engine.registry import load_script

    return load_script(REPO / "experiments" / "grid_shooting.py").EXPERIMENT


@pytest.mark.parametrize("sets, sweep, points", [
    ({}, {"agent.learning_rate": [0.1, 0.25, 0.5]}, 6),  # the default sweep stays
    ({"agent.lem.initial_difficulty": 0.0}, {"agent.learning_rate": [0.1, 0.25, 0.5]},
     3),  # --set fixes the default sweep's path
    ({}, {"agent.lem.initial_difficulty": [0.0, 0.5, 1.0]}, 3),  # --sweep replaces it
    ({}, {}, 2),
])
def test_sweep_announces_the_points_it_runs(grid_shooting, sets, sweep, points):
    from vbl.engine.runner import describe_sweep, resolve
    from vbl.engine.sweep import make_plan

    n, seeds, text = describe_sweep(grid_shooting, sets, sweep, 4, quick=True)
    assert n == points and seeds == 4 and max(map(len, text.splitlines())) <= 100
    assert text.startswith(f"grid_shooting: {points} sweep point{'s' * (points > 1)} x 4 seeds")
    config, full, seeds, _ = resolve(grid_shooting, sets, sweep, 4, 0, quick=True)
    plan = make_plan(grid_shooting, config, full, seeds)
    assert len(plan.points) == points and plan.num_learners == points * 4
    if "agent.lem.initial_difficulty" not in sweep and not sets:
        assert "agent.lem.initial_difficulty = 1.0,0.0 (the experiment's default sweep" in text


def test_set_and_sweep_of_one_path_is_an_error(grid_shooting):
    from vbl.engine.runner import resolve
    from vbl.params import ParamError

    with pytest.raises(ParamError, match="both set and swept"):
        resolve(grid_shooting, {"agent.learning_rate": 0.1},
                {"agent.learning_rate": [0.1, 0.2]}, 2)


def _tree_digest(d: Path) -> dict[str, str]:
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*")) if p.is_file()}


def test_tabular_program_names_its_success_curves_by_what_they_measure():
    from vbl.programs.tabular import curve_metric

    assert curve_metric({"eval_success": 1, "train_success": 0}) == "eval_success"
    assert curve_metric({"train_success": 0}) == "train_success"


FAKE_BENCH = '''"""A benchmark written like the real ones: results under ROOT/benchmarks/results."""
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.hardware import CPU  # noqa: E402  (a helper module beside it)

if __name__ == "__main__":
    res = ROOT / "benchmarks" / "results"
    res.mkdir(exist_ok=True)
    rows = [dict(config="default", datasets=1024, x_sippy_cpu=2.4 if "--quick" in sys.argv
                 else 200.0)]
    (res / "cva_throughput.json").write_text(json.dumps(dict(cpu=CPU, rows=rows)))
'''


def test_bench_out_leaves_the_source_results_alone(tmp_path):
    """`vbl bench --quick --out DIR` on a benchmark folder laid out as the source tree's:
    the results land in DIR, the folder's own results/ stay as they were, helper modules
    are not run, and the headline figure is printed beside its target with a verdict."""
    src = tmp_path / "tree"
    (src / "benchmarks" / "results").mkdir(parents=True)
    (src / "benchmarks" / "cva_throughput.py").write_text(FAKE_BENCH)
    (src / "benchmarks" / "hardware.py").write_text("CPU = 'test cpu'\n")
    committed = src / "benchmarks" / "results" / "cva_throughput.json"
    committed.write_text('{"committed": true}')
    before = _tree_digest(src / "benchmarks")
    env = {"VBL_BENCH_DIR": str(src / "benchmarks")}
    r = _vbl(["bench", "--quick", "--out", "out"], tmp_path, **env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree_digest(src / "benchmarks") == before
    assert json.loads((tmp_path / "out" / "cva_throughput.json").read_text())["cpu"] == \
        "test cpu"
    assert not (tmp_path / "out" / ".scripts").exists()
    assert "== hardware" not in r.stdout
    assert ("cva_throughput: 2.4 x SIPPY CPU time, default identify, 1024 data sets; "
            "target >= 100: not met") in r.stdout
    # the committed results change only when asked: --out the folder's own results/
    r = _vbl(["bench", "--out", str(src / "benchmarks" / "results"), "cva_throughput"],
             tmp_path, **env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "target >= 100: met" in r.stdout and "committed" not in committed.read_text()
    r = _vbl(["bench", "nope"], tmp_path, **env)
    assert r.returncode == 2 and r.stderr.startswith("vbl: error: unknown benchmark(s) ['nope']")


def test_the_source_trees_benchmarks_leave_out_helper_modules():
    from vbl.engine.bench import TARGETS, benchmarks

    found = benchmarks(REPO / "benchmarks")
    assert "hardware" not in found and "numpy_env" not in found
    assert set(found) == set(TARGETS)


def test_a_non_editable_install_finds_the_source_trees_benchmarks(monkeypatch, tmp_path):
    """Installed elsewhere (``pip install .``), the package has no benchmarks/ beside it;
    run from the source tree, the benchmarks are found there (the experiments ship inside
    the package: tests/test_packaging.py)."""
    import vbl
    from vbl.engine.bench import bench_dir

    monkeypatch.delenv("VBL_BENCH_DIR", raising=False)
    site = tmp_path / "site-packages" / "vbl"
    site.mkdir(parents=True)
    monkeypatch.setattr(vbl, "__file__", str(site / "__init__.py"))
    monkeypatch.chdir(REPO)
    assert bench_dir() == REPO / "benchmarks"


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_real_bench_quick_out_leaves_the_committed_results_alone(tmp_path):
    """A cheap benchmark: Table 2's step at 8 and 16 learners, compiled in 5 processes
    (about 9 min at load 10 on 2 cores, the compilations)."""
    committed = REPO / "benchmarks" / "results"
    before = _tree_digest(committed)
    r = _vbl(["bench", "--quick", "--out", str(tmp_path / "out"), "sweep_scaling"], tmp_path,
             timeout=1500)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree_digest(committed) == before
    assert (tmp_path / "out" / "sweep_scaling.json").exists()
    assert "sweep_scaling: " in r.stdout and "target: none stated" in r.stdout


def test_python_experiment_script_prints_no_xla_log_lines(tmp_path):
    """`python experiments/x.py` (the same as `vbl run x`): XLA's warning and error lines of
    programs loaded from the compilation cache stay hidden, though the script loads JAX
    before `main_for` runs. Whether XLA writes such lines at all depends on the machine
    (CPU features of the cached programs), so VBL_XLA_LOGS is checked on the setting below."""
    env = _env(VBL_JAX_CACHE=str(tmp_path / "cache"))
    env.pop("TF_CPP_MIN_LOG_LEVEL", None)
    cmd = [sys.executable, str(REPO / "experiments" / "toy_bandit.py"), "--quick", "--seeds",
           "2", "--set", "env.num_arms=3", "--set", "train.pulls_per_chunk=5", "--overwrite",
           "--out", str(tmp_path / "run")]
    xla_line = re.compile(r"^[IWEF]\d{4} ", re.M)
    outs = [subprocess.run(cmd, env=e, capture_output=True, text=True, timeout=TIMEOUT)
            for e in (env, env)]
    for r in outs:
        assert r.returncode == 0, r.stderr[-3000:]
    assert "toy_bandit: 1 sweep point x 2 seeds" in outs[1].stdout
    assert not xla_line.search(outs[1].stderr), outs[1].stderr[-3000:]  # cached programs


@pytest.mark.parametrize("env, level", [
    ({}, "3"), ({"VBL_XLA_LOGS": "1"}, None), ({"VBL_XLA_LOGS": "0"}, "3"),
    ({"TF_CPP_MIN_LOG_LEVEL": "0"}, "0"), ({"TF_CPP_MIN_LOG_LEVEL": "2"}, "3")])
def test_xla_log_level_follows_the_users_request(monkeypatch, env, level):
    """XLA's C++ log is quiet (level 3) unless VBL_XLA_LOGS or a verbose level asks for it."""
    from vbl.engine.errors import quiet_xla_env

    for name in ("VBL_XLA_LOGS", "TF_CPP_MIN_LOG_LEVEL"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    quiet_xla_env()
    assert os.environ.get("TF_CPP_MIN_LOG_LEVEL") == level


def test_a_vbl_folder_in_the_working_directory_is_one_line(tmp_path):
    """An empty ``vbl/`` folder where the user runs ``python -m vbl.cli`` hides the package
    (a namespace package); the command says so in one line instead of a TypeError."""
    (tmp_path / "vbl").mkdir()
    env = _env()
    env.pop("PYTHONPATH", None)  # the package found through its install, as a user's is
    r = subprocess.run([sys.executable, "-m", "vbl.cli", "list"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=TIMEOUT)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "a folder named vbl" in lines[0] and str((tmp_path / "vbl").resolve()) in lines[0]


def test_a_taken_out_is_refused_before_jax_loads(tmp_path):
    """`vbl run X --out TAKEN` answers before the experiment (and JAX) is imported."""
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "notes.txt").write_text("mine")
    code = ("import sys; from vbl.cli import main; "
            f"code = main(['run', 'grid_shooting', '--out', {str(taken)!r}]); "
            "print(code, 'jax' in sys.modules, 'vbl.experiments' in str(sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=_env(),
                       capture_output=True, text=True, timeout=TIMEOUT)
    assert r.stdout.split() == ["1", "False", "False"], (r.stdout, r.stderr)
    assert "exists and is not empty; use --resume" in r.stderr
    assert (taken / "notes.txt").read_text() == "mine"
