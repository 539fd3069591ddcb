"""landing stage."""
