"""Function shape in vbl/: no function longer than :data:`MAX_LINES` lines or branching more
than :data:`MAX_BRANCHES` times without a comment saying why it must be so.

The rule, kept simple so anyone can recount by hand:

* lines: from the ``def`` line to the function's last line (decorators not counted);
* branches: every ``if`` statement, conditional expression (``a if c else b``), ``for``,
  ``while``, ``try``, ``with`` and boolean operation (one per ``and``/``or`` chain), plus
  every ``if`` clause of a comprehension, anywhere inside the function (nested functions
  count towards the function that holds them);
* a function over either limit passes when the comment block right above its ``def`` (or
  its decorators) has a line starting ``# shape:`` that says why it must be so.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
MAX_BRANCHES = 15
BRANCH_NODES = (ast.If, ast.IfExp, ast.For, ast.AsyncFor, ast.While, ast.Try, ast.TryStar,
                ast.With, ast.AsyncWith, ast.BoolOp)


def branches(fn: ast.AST) -> int:
    """Branches of a function by the rule in the module docstring."""
    n = 0
    for node in ast.walk(fn):
        if node is fn:
            continue
        if isinstance(node, BRANCH_NODES):
            n += 1
        elif isinstance(node, ast.comprehension):
            n += len(node.ifs)
    return n


def _justified(lines: list[str], fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    first = min([fn.lineno, *(d.lineno for d in fn.decorator_list)])
    i = first - 2  # 0-based index of the line above the def / first decorator
    while i >= 0 and lines[i].lstrip().startswith("#"):
        if lines[i].lstrip().startswith("# shape:"):
            return True
        i -= 1
    return False


def offenders(source: str, name: str) -> list[str]:
    """``"name:line function (N lines, M branches)"`` of every function of ``source`` over
    a limit without a ``# shape:`` comment."""
    lines = source.splitlines()
    out = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        n_lines, n_branches = fn.end_lineno - fn.lineno + 1, branches(fn)
        if (n_lines > MAX_LINES or n_branches > MAX_BRANCHES) and not _justified(lines, fn):
            out.append(f"{name}:{fn.lineno} {fn.name} ({n_lines} lines, "
                       f"{n_branches} branches)")
    return out


def _all_offenders() -> list[str]:
    out = []
    for py in sorted((ROOT / "vbl").rglob("*.py")):
        out += offenders(py.read_text(), py.relative_to(ROOT).as_posix())
    return out


def test_branch_count_by_hand():
    src = '''
def f(x, ys):
    if x and ys or not x:            # if + 2 boolops (or of (and))
        pass
    for y in ys:                     # for
        while y:                     # while
            y -= 1
    try:                             # try
        with open("a") as h:         # with
            pass
    except OSError:
        pass
    z = [y for y in ys if y if y > 1]   # 2 comprehension ifs
    return 1 if z else 0            # conditional expression
'''
    fn = ast.parse(src).body[0]
    assert branches(fn) == 10


def test_offenders_and_the_shape_comment():
    body = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(MAX_BRANCHES + 1))
    bare = f"def g(x):\n{body}"
    assert offenders(bare, "m.py") == [f"m.py:1 g ({2 * MAX_BRANCHES + 3} lines, "
                                       f"{MAX_BRANCHES + 1} branches)"]
    why = "# shape: a lookup table written out\n@staticmethod\n" + bare
    assert offenders(why, "m.py") == []
    other = "# a comment that says nothing of shape\n" + bare
    assert len(offenders(other, "m.py")) == 1
    long = "def h():\n" + "    x = 1\n" * MAX_LINES
    assert offenders(long, "m.py") == [f"m.py:1 h ({MAX_LINES + 1} lines, 0 branches)"]


def test_no_long_or_branchy_function_without_a_reason():
    bad = _all_offenders()
    assert not bad, ("functions over the shape limits (split them into named steps, or say "
                     "why they must be so in a '# shape:' comment above the def):\n"
                     + "\n".join(bad))
