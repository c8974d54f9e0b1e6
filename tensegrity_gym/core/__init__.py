"""Data and rules: structures, models, states, per-copy parameters, the integrator registry, errors and input checks (imports nothing above it)."""
