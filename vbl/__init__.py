"""vbl: a JAX-vectorised batch experiment engine for vision-based robot learning.

Importing vbl changes no global JAX setting: the ``vbl`` command turns on the persistent
compilation cache, and the engine enables 64-bit types only for the duration of a run
(:mod:`vbl.engine.jax_setup`).
"""

__version__ = "0.1.0"
