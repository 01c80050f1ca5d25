"""The Markdown docs: links resolve, no work-period chronology or machine paths, no
measurement records (commit hashes, load figures, CPU models) or change history outside
benchmark results and method paragraphs, and the generated parameter tables match ``vbl
params`` (see ``vbl/engine/paramdoc.py``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)|!\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
CODE = re.compile(r"`[^`\n]*`")
CHRONOLOGY = re.compile(
    r"\bsessions?[\s-]*\d|\b(?:this|that|next|previous|earlier|later|each|every|one|"
    r"since|in|of)\s+session\b|\bStatus \(", re.I)
MACHINE_PATH = re.compile(r"/tmp/|/work/")

# Docs describe the code as it is. Measurement records (the commit measured, the machine's
# load and CPU model) belong in benchmark result files (benchmarks/results/, not docs),
# the run folders under docs/results/ (written by runs), the README's generated blocks
# (between `<!-- vbl X -->` and `<!-- /vbl X -->`) and method paragraphs, marked in the
# Markdown source as `<!-- method -->` ... `<!-- /method -->` (invisible when rendered):
# the machine, load and command of a measurement the surrounding text cites.
EXEMPT_BLOCK = re.compile(r"<!-- (vbl|method)\b[^>]*-->.*?<!-- /\1\b[^>]*-->", re.S)
COMMIT_HASH = re.compile(r"(?<![\w./-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}"
                         r"(?![\w-])")
LOAD_FIGURE = re.compile(r"\bload(?:\s+averages?)?\s*(?:of|about|around|near|at|~|=|:)?"
                         r"\s*~?\d", re.I)
CPU_MODEL = re.compile(r"\b(?:Xeon|EPYC|Ryzen|Threadripper|Opteron|Core i[3579])\b")
HISTORY = re.compile(
    r"\b(?:previously|formerly|originally|no longer|nowadays|until now|any ?more)\b"
    r"|\bearlier (?:code|versions?|defaults?|commits?|camera|implementations?|variants?)\b"
    r"|\b(?:the|its) old (?:one|camera|code|version|kernel|defaults?)\b"
    r"|\bit replaced\b|\b(?:was|were)\b[^.;:]{1,60}?\bnow\b"
    r"|\bnow (?:uses?|takes?|gives?|runs?|is|are)\b", re.I)


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _prose(text: str) -> str:
    """``text`` without fenced code blocks and inline code (links there are not links)."""
    return CODE.sub("", FENCE.sub("", text))


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    s = re.sub(r"[`*_]", "", heading.strip().lower())
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", path.read_text()).splitlines():
        m = re.match(r"#{1,6}\s+(.*)", line)
        if not m:
            continue
        s = _slug(m.group(1))
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_relative_links_resolve(doc: Path):
    bad = []
    for m in LINK.finditer(_prose(doc.read_text())):
        target = m.group(1) or m.group(2)
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists():
            bad.append(f"{target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"{target} (no heading #{anchor})")
    assert not bad, f"{_rel(doc)}: broken links: {bad}"


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_no_chronology_or_machine_paths(doc: Path):
    text = doc.read_text()
    found = [m.group(0) for m in CHRONOLOGY.finditer(text)]
    found += [m.group(0) for m in MACHINE_PATH.finditer(text)]
    assert not found, f"{_rel(doc)}: work-period chronology or machine paths: {found[:10]}"


RECORD_FREE = [d for d in DOCS if not _rel(d).startswith("docs/results/")]


def records_and_history(text: str) -> list[str]:
    """Commit hashes, load figures, CPU models and change history in ``text`` outside its
    generated blocks and method paragraphs (lines joined: a phrase may wrap)."""
    prose = re.sub(r"\s+", " ", EXEMPT_BLOCK.sub(" ", text))
    return [m.group(0) for p in (COMMIT_HASH, LOAD_FIGURE, CPU_MODEL, HISTORY)
            for m in p.finditer(prose)]


@pytest.mark.parametrize("doc", RECORD_FREE, ids=_rel)
def test_no_measurement_records_or_history(doc: Path):
    found = records_and_history(doc.read_text())
    assert not found, (f"{_rel(doc)}: commit hashes, load figures, CPU models or change "
                       f"history outside a method paragraph: {found[:10]}")


def test_records_and_history_pattern():
    for bad in ("code `3f376aec591b`", "--base c156c19", "at load 13", "load average 0.5-1.4",
                "(load ~12)", "a quiet 2-core Intel Xeon", "on the AMD EPYC",
                "the earlier defaults (kick cone 30 deg)", "it was 3 ms and is now 2 ms",
                "`step` no longer splits its key", "previously a scan",
                "the defaults now use a 45 deg cone", "the old one's CPU time"):
        assert records_and_history(bad), bad
    for ok in ("the earlier work's learner", "darker for earlier divisions", "1e-4 of each",
               "int32 and float32", "the load average at the start and the end",
               "exercise 0.5, then 1", "a 2-core machine", "the box its features fall in now",
               "deadbeef", "1234567", "sha-256 of the file", "<!-- method -->at load 3, "
               "commit 3f376aec591b, AMD EPYC<!-- /method -->",
               "<!-- vbl reproduce runs -->load average 2.94<!-- /vbl reproduce runs -->"):
        assert not records_and_history(ok), ok


def test_link_checker_catches_a_broken_link(tmp_path: Path):
    doc = tmp_path / "a.md"
    (tmp_path / "b.md").write_text("# Hello world\n")
    doc.write_text("[ok](b.md#hello-world) [no](c.md) [anchor](b.md#nope) `[code](x.md)`\n")
    targets = [m.group(1) for m in LINK.finditer(_prose(doc.read_text()))]
    assert targets == ["b.md#hello-world", "c.md", "b.md#nope"]
    assert _anchors(tmp_path / "b.md") == {"hello-world"}


def test_chronology_pattern():
    for bad in ("in session 7", "Session-5 options", "Status (session 3)", "since session 6"):
        assert CHRONOLOGY.search(bad), bad
    for ok in ("a Python process", "the sessions of a server"):
        assert not CHRONOLOGY.search(ok), ok


REGION_DOCS = [d for d in DOCS if "<!-- params:" in d.read_text()]


@pytest.mark.parametrize("doc", REGION_DOCS, ids=_rel)
def test_parameter_tables_match_vbl_params(doc: Path):
    from vbl.engine.paramdoc import regions, table

    stale = [f"{exp} {','.join(prefixes)}" for exp, prefixes, body in regions(doc.read_text())
             if body.strip() != table(exp, prefixes).strip()]
    assert not stale, (f"{_rel(doc)}: parameter tables out of date with `vbl params`: {stale}; "
                       f"regenerate: python -m vbl.engine.paramdoc {_rel(doc)}")


def test_every_parameter_table_in_these_docs_is_generated():
    """The reference docs rewritten for the generated tables hold no hand-copied ones."""
    header = "| parameter | default | unit | source | static | meaning | allowed |"
    for name in ("docs/agents.md", "docs/state_spaces.md", "docs/cva_learning.md"):
        text = (ROOT / name).read_text()
        from vbl.engine.paramdoc import REGION

        outside = REGION.sub("", text)
        assert header not in outside, f"{name}: a parameter table outside a params region"


RUN_CMD = re.compile(r"vbl run ([\w./-]+)((?:\s+(?:--[\w-]+(?:[ =]\"?[^\s`\"]+\"?)?))*)")
OPTION = re.compile(r"--(set|sweep)[ =]\"?([\w.]+)=")
PRESET = re.compile(r"--preset[ =]([\w-]+)")


def _commands(text: str) -> list[tuple[str, list[str]]]:
    """(experiment, [parameter paths of --set / --sweep, and "preset:NAME" of --preset]) of
    every `vbl run NAME ...` in code (inline spans may wrap lines; fenced blocks)."""
    code = [m.group(0) for m in FENCE.finditer(text)]
    code += re.findall(r"`[^`]+`", FENCE.sub("", text))
    out = []
    for chunk in code:
        chunk = re.sub(r"\s+", " ", chunk)
        for m in RUN_CMD.finditer(chunk):
            out.append((m.group(1), [p for _, p in OPTION.findall(m.group(2))]
                        + [f"preset:{n}" for n in PRESET.findall(m.group(2))]))
    return out


def test_commands_pattern():
    text = ("run `vbl run fig9_incremental --seeds 4 --set\nlearner.bins=8 --sweep a.b=1,2 "
            "--preset p_1`")
    assert _commands(text) == [("fig9_incremental", ["learner.bins", "a.b", "preset:p_1"])]


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_vbl_run_commands_name_real_experiments_and_parameters(doc: Path):
    """A `vbl run NAME --set PATH=... --preset P` in the docs names a registered experiment,
    parameters its config has and presets it defines (a renamed parameter makes a
    documented command stale)."""
    from vbl.engine import get
    from vbl.params import ParamError, get_path

    bad = []
    for name, paths in _commands(doc.read_text()):
        if "_" not in name or name.endswith(".py") or "/" in name:
            continue  # placeholders (NAME), prose ("vbl run first"), script paths
        try:
            exp = get(name)
            cfg = exp.default_config
        except Exception as e:  # noqa: BLE001 - report every stale command at once
            bad.append(f"{name}: {e}")
            continue
        for p in paths:
            if p.startswith("preset:"):
                if p[7:] not in exp.presets:
                    bad.append(f"vbl run {name} --preset {p[7:]}")
                continue
            try:
                get_path(cfg, p)
            except ParamError:
                bad.append(f"vbl run {name} ... {p}")
    assert not bad, f"{_rel(doc)}: stale commands: {bad}"


def test_probe_scripts_are_cited_and_exist():
    probes = {p.name for p in (ROOT / "benchmarks" / "probes").glob("*.py")}
    cited = set()
    for doc in DOCS:
        cited |= set(re.findall(r"benchmarks/probes/([a-z0-9_]+\.py)", doc.read_text()))
    assert cited <= probes, f"docs cite missing probes: {sorted(cited - probes)}"
    assert probes <= cited, f"probes no doc cites: {sorted(probes - cited)}"


CITATION = re.compile(r"(?<![\w/])docs/([\w./-]+\.md)`{0,2}"
                      r"(?:(?:,\s*|\s+\()(?:#\s*)?\"([^\"]+)\")?")


def _headings(path: Path) -> list[str]:
    return [re.sub(r"\s+", " ", m.group(1)).strip() for m in
            re.finditer(r"^#{1,6}\s+(.*)$", FENCE.sub("", path.read_text()), re.M)]


def test_docs_cited_in_code_exist_with_the_cited_section():
    """Every ``docs/X.md`` a comment or docstring under vbl/, experiments/, benchmarks/ cites
    exists, and a section named in quotes right after it (``docs/X.md, "Heading"`` or
    ``docs/X.md ("Heading")``, possibly wrapped onto a ``#`` comment line) is part of a
    heading of X.md."""
    sample = 'a (docs/a_1/b.md, "Why\n    # it holds") and ``docs/c.md`` ("Numbers"), docs/d.md.'
    assert [(m.group(1), m.group(2)) for m in CITATION.finditer(sample)] == [
        ("a_1/b.md", "Why\n    # it holds"), ("c.md", "Numbers"), ("d.md", None)]
    bad = []
    for top in ("vbl", "experiments", "benchmarks"):
        for py in sorted((ROOT / top).rglob("*.py")):
            text = py.read_text()
            for m in CITATION.finditer(text):
                line = text.count("\n", 0, m.start()) + 1
                doc = ROOT / "docs" / m.group(1)
                where = f"{_rel(py)}:{line}: docs/{m.group(1)}"
                if not doc.is_file():
                    bad.append(f"{where} (no such file)")
                elif m.group(2):
                    section = re.sub(r"\s*\n\s*#?\s*", " ", m.group(2)).strip()
                    if not any(section in h for h in _headings(doc)):
                        bad.append(f'{where} (no heading containing "{section}")')
    assert not bad, "stale doc citations in code:\n" + "\n".join(bad)
