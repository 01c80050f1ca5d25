"""vbl.sysid."""
