"""vbl: a JAX-vectorised batch experiment engine for vision-based robot learning."""

import jax

# Identification and Q-value bookkeeping need float64 where asked for; arrays stay
# float32 unless a module requests float64 explicitly.
jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
