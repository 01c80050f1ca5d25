"""Keep XLA from recomputing a value in each of its consumers.

XLA fuses cheap elementwise work into every consumer that reads it; when many consumers
read the same value (a pixel's three channels, a box's four clamped ends), each recomputes
it and everything it is made of. Dividing by a 1 the compiler cannot see stops that: the
value is computed once and stored, and stays exactly the same.
"""

from __future__ import annotations

__all__ = ["opaque_one", "stored", "stored_once"]


def opaque_one(x):
    """Exactly 1 for finite ``x``, but not known to the compiler (the ``one`` of
    :func:`stored`)."""
    return x * 0.0 + 1.0


def stored(x, one):
    """``x / one`` with ``one`` == 1 not known to the compiler: exactly ``x``, computed once
    and stored instead of copied into each of its consumers."""
    return x / one


def stored_once(x):
    """:func:`stored` with a ``one`` made from ``x``'s own first element (``x`` finite)."""
    return stored(x, opaque_one(x.reshape(-1)[0]))
