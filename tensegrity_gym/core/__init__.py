"""Data and rules of the package: the layer every other one may import."""
