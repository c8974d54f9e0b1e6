"""Scripts: tools."""
