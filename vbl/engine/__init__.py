"""vbl.engine."""
