"""Benchmark, evaluation, figure and maintenance scripts of the repository (not installed). Run them from the repository root as modules: ``python -m scripts.<group>.<name>``."""
