"""Independent plain-NumPy references of vbl's JAX code (for tests and benchmarks only)."""
