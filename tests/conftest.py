"""Shared pytest setup: make the repository root importable so tests can use
``from tests.reference import ...`` (the independent references)."""

import pathlib
import sys

import pytest

_ROOT = str(pathlib.Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

# The suite compiles the same programs in every run: keep them on disk as the ``vbl``
# command does (VBL_JAX_CACHE=0 turns it off).
from vbl.engine.jax_setup import use_compilation_cache  # noqa: E402

use_compilation_cache()


@pytest.fixture(scope="module")
def engine_precision():
    """64-bit types on for a whole test module, as the engine runs experiments (for modules
    that test library code the engine runs in float64: ``pytestmark =
    pytest.mark.usefixtures("engine_precision")``)."""
    from vbl.engine.jax_setup import engine_precision as scope

    with scope():
        yield
