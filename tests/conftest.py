"""Shared pytest setup: make the repository root importable so tests can use
``from tests.reference import ...`` (the independent references)."""

import pathlib
import sys

_ROOT = str(pathlib.Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
