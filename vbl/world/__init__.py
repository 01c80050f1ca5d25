"""vbl.world."""
