"""vbl.spaces."""
