"""vbl.envs."""
