"""The backends by name: what ``backend=`` of :func:`tensegrity_gym.physics.step` selects.

=========  ==========================================  =====================  ==================
name       what runs the equations                     methods                options
=========  ==========================================  =====================  ==================
``numba``  compiled CPU kernels over packed buffers     every method (the      none
           (:mod:`tensegrity_gym.backends.numba`)        adaptive and implicit
                                                        ones evaluate forces
                                                        on it)
``torch``  batched tensors on a torch device, float32   ``semi_implicit_euler``,  ``device``, ``dtype``
           or float64 (:mod:`tensegrity_gym.backends    ``rk4``
           .torch`)
=========  ==========================================  =====================  ==================

``"auto"`` is ``"numba"``. ``"numpy"`` is not a backend: the NumPy equations are the test oracle
(:data:`tensegrity_gym.core.integrators.NUMPY_REMOVED`). Each backend's ``step_state`` has
:func:`tensegrity_gym.physics.step`'s contract for its fixed-step methods on a NumPy
:class:`~tensegrity_gym.core.model.State` (SI units); adding a backend is adding its subpackage
and a row here (``docs/architecture.md``, "a backend").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..backends.numba import api as numba_api
from ..backends.torch import driver as torch_driver
from ..core.integrators import EXPLICIT, NUMPY_REMOVED

__all__ = ["Backend", "BACKENDS", "ALIASES", "get_backend"]


@dataclass(frozen=True)
class Backend:
    """One backend: its ``name``, a one-line ``description``, ``step_state(model, state, dt,
    integrator, *, rest_length, force_density, external, project, n_steps, params, **options)``
    for the fixed-step ``methods``, and the extra keyword ``options`` it takes."""

    name: str
    description: str
    step_state: Callable
    methods: tuple[str, ...]
    options: tuple[str, ...] = ()


BACKENDS: dict[str, Backend] = {
    "numba": Backend("numba", "compiled CPU kernels (numba) over one packed buffer per model", numba_api.step,
                     EXPLICIT),
    "torch": Backend("torch", "batched torch tensors on a device, float32 or float64", torch_driver.step_state,
                     EXPLICIT, ("device", "dtype")),
}
#: other names ``backend=`` takes
ALIASES = {"auto": "numba"}


def get_backend(name) -> Backend:
    """The :class:`Backend` of ``name`` (or an alias); ValueError naming ``backend`` otherwise."""
    if name == "numpy":
        raise ValueError(f"backend: {NUMPY_REMOVED}")
    if not isinstance(name, str) or ALIASES.get(name, name) not in BACKENDS:
        raise ValueError(f"backend: unknown {name!r}; choose one of {sorted(ALIASES) + sorted(BACKENDS)}")
    return BACKENDS[ALIASES.get(name, name)]
