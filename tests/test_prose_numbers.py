"""Prose that cannot drift: every number in the README's and the findings' prose is in a
committed file the text cites, and every figure the docs show comes from a committed
command (a run's or benchmark's output folder, or an ``--out PATH`` the text gives).

A number in prose (outside fenced code, inline code, HTML comments, the generated blocks
-- ``vbl`` blocks and the probe tables that ``tests/test_probes.py`` pins to their
committed results file -- and the method paragraphs that ``tests/test_docs.py`` exempts)
must equal, at the precision it is written, a value of one of the document's **sources**,
as it is or scaled by a unit change (x100 for a percentage, s to min or h, k, M, G, m, u,
n):

* every committed results file the document cites, by a Markdown link or an inline-code
  path: ``.json``, ``.jsonl`` and ``.csv`` files, the ``.md`` files written by runs and
  benchmarks (under ``docs/results/`` and ``benchmarks/results/``), and a run folder's
  ``summary.json``, ``config.json``, ``report.md``, ``reproduce.json`` and ``tune.json``;
* the experiment scripts, probes and library modules it cites (``.py`` under
  ``experiments/``, ``benchmarks/`` and ``vbl/``), where the defaults are written, and
  ``pyproject.toml``;
* the paths a ``<!-- sources: PATH ... -->`` comment names (for a file the text names in
  words), and always ``vbl/programs/paper.py``, the paper's figures.

Not checked: integers up to 10 (counts in running text), the numbers of Tables, Figures,
Sections, equations and issues, and the 95 of "95 %" intervals. Another Markdown page is
never a source: prose does not back prose.

    python tests/test_prose_numbers.py            # every unbacked number, per document
    python tests/test_prose_numbers.py README.md  # one document
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_docs import CODE, EXEMPT_BLOCK, FENCE  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CHECKED = sorted([ROOT / "README.md", *(ROOT / "docs" / "findings").glob("*.md")])
ALWAYS = ("vbl/programs/paper.py",)

#: a number as prose writes it: thousands commas, decimals, an exponent; not part of a
#: name (x3, fig5), a version (0.9.2) or a path
NUMBER = re.compile(r"(?<![\w.])(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:e-?\d+)?"
                    r"(?!\.\d)(?![A-Za-wyz_\d])")
NOT_A_QUANTITY = re.compile(
    r"(?:\b(?:Tables?|Figures?|Figs?\.|Sec\.|Sections?|Eqs?\.|equations?|issues?)|#)"
    r"\s*(?:\d+(?:\.\d+)*\s*(?:,|and|-|to|or)\s*)*$", re.I)
INTERVAL_LEVEL = re.compile(r"\s*%\s*(?:\w+\s+)?(?:interval|confidence|CI)", re.I)
#: a table a probe writes from its committed results file, which tests/test_probes.py
#: compares with that file (the means of per-seed values, which the file does not hold)
PROBE_TABLE = re.compile(r"<!-- (table2_ablation|table2_tuned) -->.*?<!-- /\1 -->", re.S)
CITED = re.compile(r"\]\(([^)\s#]+)[^)]*\)|`([\w./-]+)`")
DECLARED = re.compile(r"<!--\s*sources:(.*?)-->", re.S)
RESULT_DIRS = ("docs/results/", "benchmarks/results/")
CODE_DIRS = ("experiments/", "benchmarks/", "vbl/")
RUN_FILES = ("summary.json", "config.json", "report.md", "reproduce.json", "tune.json")
#: unit changes a prose number may carry against its source value
SCALES = (1.0, 100.0, 0.01, 1 / 60, 1 / 3600, 1e3, 1e-3, 1e6, 1e-6, 1e9, 1e-9)
SMALL_COUNT = 10
FILE_NUMBER = re.compile(r"(?<!\w)(?<![^.]\.)\d[\d,]*(?:\.\d+)?(?:e-?\d+)?")


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _is_source(path: Path) -> bool:
    rel = _rel(path)
    if path.is_dir():
        return any((path / n).exists() for n in RUN_FILES)
    if path.suffix in (".json", ".jsonl", ".csv"):
        return True
    if path.suffix == ".md":
        return rel.startswith(RESULT_DIRS)
    return (path.suffix == ".py" and rel.startswith(CODE_DIRS)) or rel == "pyproject.toml"


def sources(doc: Path, text: str) -> list[Path]:
    """The committed files ``doc`` cites (see the module docstring), sorted."""
    found = {ROOT / p for p in ALWAYS}
    cited = [m.group(1) or m.group(2) for m in CITED.finditer(text)]
    for m in DECLARED.finditer(text):
        cited += m.group(1).split()
    for target in cited:
        for base in (doc.parent, ROOT):
            p = (base / target).resolve()
            if p.exists() and ROOT in p.parents and _is_source(p):
                found.add(p)
                break
    return sorted(found)


def _json_numbers(x, out: set[float]) -> None:
    if isinstance(x, bool) or x is None:
        return
    if isinstance(x, (int, float)):
        out.add(abs(float(x)))
    elif isinstance(x, dict):
        for v in x.values():
            _json_numbers(v, out)
    elif isinstance(x, list):
        for v in x:
            _json_numbers(v, out)
    elif isinstance(x, str):
        _text_numbers(x, out)


def _text_numbers(text: str, out: set[float]) -> None:
    for m in FILE_NUMBER.finditer(text):
        try:
            out.add(abs(float(m.group().replace(",", ""))))
        except ValueError:
            pass


def source_values(paths: list[Path]) -> set[float]:
    """Every number in ``paths`` (absolute values; run folders through their RUN_FILES)."""
    out: set[float] = set()
    for path in paths:
        if path.is_dir():
            out |= source_values([path / n for n in RUN_FILES if (path / n).exists()])
        elif path.suffix == ".json":
            _json_numbers(json.loads(path.read_text()), out)
        elif path.suffix == ".jsonl":
            for line in path.read_text().splitlines():
                if line.strip():
                    _json_numbers(json.loads(line), out)
        else:
            _text_numbers(path.read_text(errors="replace"), out)
    return out


def prose_of(text: str) -> str:
    """``text`` without what is not prose: generated blocks, method paragraphs, code, HTML
    comments and link targets (each replaced by a space, so line numbers shift little)."""
    text = EXEMPT_BLOCK.sub(" ", text)
    text = PROBE_TABLE.sub(" ", text)
    text = FENCE.sub(" ", text)
    text = re.sub(r"<!--.*?-->", " ", text, flags=re.S)
    text = CODE.sub(" ", text)
    return re.sub(r"\]\([^)]*\)", "]", text)


def prose_numbers(text: str) -> list[tuple[str, str]]:
    """``(number, context)`` for each checked number of ``text``'s prose."""
    prose = prose_of(text)
    out = []
    for m in NUMBER.finditer(prose):
        token = m.group()
        before, after = prose[max(0, m.start() - 40):m.start()], prose[m.end():m.end() + 30]
        if NOT_A_QUANTITY.search(before):
            continue
        if token == "95" and INTERVAL_LEVEL.match(after):
            continue
        if "." not in token and "e" not in token and float(token.replace(",", "")) <= SMALL_COUNT:
            continue
        context = re.sub(r"\s+", " ", prose[max(0, m.start() - 50):m.end() + 25])
        out.append((token, context))
    return out


def backed(token: str, values: set[float]) -> bool:
    """Whether ``token`` is a value of ``values`` (or a unit change of one) written to the
    precision of ``token``: 41.3 is 0.4131 as a percentage, not 0.4141."""
    x = float(token.replace(",", ""))
    decimals = len(token.split(".")[1].split("e")[0]) if "." in token else 0
    if "e" in token:
        return any(math.isclose(v * s, x, rel_tol=1e-3) for v in values for s in SCALES)
    half = 0.5 * 10.0 ** -decimals * (1 + 1e-9)
    return any(abs(v * s - x) <= half for v in values for s in SCALES)


def unbacked(doc: Path) -> list[tuple[str, str]]:
    """The numbers of ``doc``'s prose that none of its sources holds."""
    text = doc.read_text()
    values = source_values(sources(doc, text))
    return [(t, c) for t, c in prose_numbers(text) if not backed(t, values)]


@pytest.mark.parametrize("doc", CHECKED, ids=_rel)
def test_every_prose_number_is_in_a_cited_committed_file(doc: Path):
    bad = unbacked(doc)
    assert not bad, (f"{_rel(doc)}: {len(bad)} numbers in no file it cites "
                     f"(python tests/test_prose_numbers.py {_rel(doc)}): "
                     + "; ".join(f"{t} in '...{c}...'" for t, c in bad[:8]))


def test_a_planted_wrong_number_fails(tmp_path: Path):
    run = tmp_path / "docs" / "results" / "run"
    run.mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"success": {"mean": 0.4131, "ci95": 0.056},
                                                  "seconds": 4288.2, "trials": 3840}))
    doc = tmp_path / "note.md"
    good = ("Table 2's current features reach 41.3 ± 5.6 % in 71.5 min over 3,840 trials "
            "([run](docs/results/run)); 16 seeds.\n")
    doc.write_text(good)
    values = source_values([run])
    assert [t for t, _ in prose_numbers(good) if not backed(t, values)] == ["16"]
    for right, wrong in (("41.3", "41.4"), ("41.3", "41.2"), ("41.3", "4.13"),
                         ("71.5", "71.4"), ("3,840", "3,841"), ("5.6", "5.7")):
        planted = good.replace(right, wrong, 1)
        assert wrong in [t for t, _ in prose_numbers(planted) if not backed(t, values)], wrong


def test_what_is_not_a_quantity_is_skipped():
    text = ("Table 2 and Figures 8, 9 and 11, Sec. 3.1.2, issue 49: a 95 % interval. "
            "Feature x3 of fig5 on jax 0.9.2, 3 cores.\n<!-- vbl report x -->41.7<!-- /vbl "
            "report -->\n```\n55.5\n```\n`77.7` <!-- 66.6 --> [a](../b/12.5.md) 95 % of 12")
    assert [t for t, _ in prose_numbers(text)] == ["95", "12"]


def test_sources_are_cited_results_and_code_never_prose(tmp_path: Path):
    doc = ROOT / "docs" / "findings" / "table2_shoot_pass.md"
    got = {_rel(p) for p in sources(doc, doc.read_text())}
    assert "benchmarks/results/table2_ablation.json" in got
    assert "vbl/programs/paper.py" in got
    assert not [p for p in got if p.endswith(".md") and not p.startswith(RESULT_DIRS)]


IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
WRITTEN_BY_RUNS = ("docs/results/", "benchmarks/results/")


def figures_without_command(doc: Path, text: str) -> list[str]:
    """The images ``doc`` shows that no committed command makes: an image is a run's or a
    benchmark's output (under WRITTEN_BY_RUNS), or the document gives the command that
    writes it (``--out PATH``, the image's path from the repository root)."""
    outs = set(re.findall(r"--out\s+([^\s`),;]+)", text))
    bad = []
    for m in IMAGE.finditer(text):
        target = (doc.parent / m.group(1)).resolve()
        if ROOT not in target.parents:
            bad.append(m.group(1))
            continue
        rel = _rel(target)
        if not rel.startswith(WRITTEN_BY_RUNS) and rel not in outs:
            bad.append(m.group(1))
    return bad


@pytest.mark.parametrize("doc", CHECKED + sorted((ROOT / "docs").glob("*.md")), ids=_rel)
def test_every_figure_comes_from_a_committed_command(doc: Path):
    bad = figures_without_command(doc, doc.read_text())
    assert not bad, f"{_rel(doc)}: figures without a run folder or an --out command: {bad}"


def test_a_figure_without_its_command_fails():
    doc = ROOT / "docs" / "render.md"
    text = doc.read_text()
    assert not figures_without_command(doc, text)
    cut = text.replace("--out docs/images/grid_learned.gif", "")
    assert figures_without_command(doc, cut) == ["images/grid_learned.gif"]
    assert not figures_without_command(doc, "![a](results/reproduce/x/y.png)")


def _main(argv: list[str]) -> int:
    docs = [ROOT / a for a in argv] or CHECKED
    total = 0
    for doc in docs:
        bad = unbacked(doc)
        total += len(bad)
        print(f"{_rel(doc)}: {len(bad)} unbacked")
        for token, context in bad:
            print(f"  {token:>10}  ...{context}...")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
