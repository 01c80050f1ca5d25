"""vbl.vision."""
