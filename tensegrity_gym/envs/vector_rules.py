"""The vector envs' rules shared by the NumPy and the torch shells: per-env seeds, no step before
``reset()``, and the autoreset mode they implement (Gymnasium's NEXT_STEP)."""
from __future__ import annotations

from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode

from ..core.checks import is_integer

__all__ = ["check_seed_value", "check_reset_called", "check_autoreset_mode"]


def check_seed_value(seed, i: int = 0):
    """``seed`` of env ``i`` as an int if it is a non-negative integer (not a bool, float or
    string), None kept; ValueError naming the env otherwise (the vector envs' seeding rule, as the
    single env's ``reset(seed=...)`` refuses them)."""
    if seed is None:
        return None
    if not is_integer(seed) or seed < 0:
        raise ValueError(f"seed: env {i}: expected a non-negative int or None, got {seed!r}")
    return int(seed)


def check_reset_called(env) -> None:
    """Gymnasium's ``ResetNeeded`` when a vector env is stepped before its first ``reset()`` (as
    ``gymnasium.make`` does for a single env)."""
    if not getattr(env, "_reset_called", False):
        raise ResetNeeded("Cannot call env.step() before calling env.reset()")


def check_autoreset_mode(kwargs: dict) -> dict:
    """``kwargs`` without ``autoreset_mode``: the vector envs autoreset on the next step only
    (``gymnasium.vector.AutoresetMode.NEXT_STEP``, or ``"next_step"``); any other request is a
    ValueError saying which autoreset mode the env implements."""
    if "autoreset_mode" not in kwargs:
        return kwargs
    kwargs = dict(kwargs)
    mode = kwargs.pop("autoreset_mode")
    ok = mode is AutoresetMode.NEXT_STEP or (isinstance(mode, str) and mode.replace("_", "").lower() == "nextstep")
    if not ok:
        raise ValueError(f"autoreset_mode: these vector envs autoreset in NEXT_STEP mode only (an env that ended "
                         f"is reset by the following step() call), got {mode!r}; choose "
                         "gymnasium.vector.AutoresetMode.NEXT_STEP or wrap single envs in SyncVectorEnv("
                         "..., autoreset_mode=...) for SAME_STEP / DISABLED")
    return kwargs
