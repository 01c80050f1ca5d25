"""vbl.agents."""
