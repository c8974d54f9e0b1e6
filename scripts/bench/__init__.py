"""Scripts: bench."""
