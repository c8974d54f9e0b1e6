"""Scripts: eval."""
