"""Scripts: figures."""
