"""Data and rules: structures, models, states, per-copy parameters and their one table, the integrator registry, errors and input checks (imports nothing above it)."""
