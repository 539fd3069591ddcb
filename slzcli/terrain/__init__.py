"""terrain stage."""
