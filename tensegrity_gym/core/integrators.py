"""The integrator and backend registry: every integrator name, alias and backend name is
decoded here, and nowhere else.

=======================  =====  ========================================================
name                     order  notes
=======================  =====  ========================================================
``semi_implicit_euler``  1      symplectic Euler (fixed step; numba, torch)
``rk4``                  4      classic Runge-Kutta (fixed step; numba, torch)
``dop853``               8      adaptive, ``scipy.integrate.solve_ivp`` (reference method)
``radau``                5      adaptive implicit (stiff strings), ``solve_ivp``
``implicit_euler``       1      backward Euler, Newton with a finite-difference Jacobian
=======================  =====  ========================================================

Backends: ``"auto"`` and ``"numba"`` (the same: the compiled kernels) and ``"torch"`` (fixed-step
methods only).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["INTEGRATORS", "IntegratorInfo", "resolve", "EXPLICIT", "IMPLICIT", "NUMPY_REMOVED", "numba_backend",
           "uses_numba", "fixed_step_name"]


@dataclass(frozen=True)
class IntegratorInfo:
    """One integrator: its canonical ``name``, convergence ``order``, whether it is ``adaptive``
    (error-controlled steps in ``scipy.integrate.solve_ivp``) or ``symplectic``, and a one-line
    ``description``."""

    name: str
    order: int
    adaptive: bool
    symplectic: bool
    description: str


INTEGRATORS: dict[str, IntegratorInfo] = {
    "semi_implicit_euler": IntegratorInfo("semi_implicit_euler", 1, False, True, "symplectic Euler"),
    "rk4": IntegratorInfo("rk4", 4, False, False, "classic 4th-order Runge-Kutta"),
    "dop853": IntegratorInfo("dop853", 8, True, False, "adaptive Dormand-Prince 8(5,3), scipy"),
    "radau": IntegratorInfo("radau", 5, True, False, "adaptive implicit Radau IIA, scipy (stiff)"),
    "implicit_euler": IntegratorInfo("implicit_euler", 1, False, False,
                                     "backward Euler, Newton, FD Jacobian (stiff strings, dissipative)"),
}
IMPLICIT = ("implicit_euler",)
EXPLICIT = ("semi_implicit_euler", "rk4")
_ALIASES = {"euler": "semi_implicit_euler", "symplectic_euler": "semi_implicit_euler",
            "semi-implicit-euler": "semi_implicit_euler", "DOP853": "dop853", "Radau": "radau"}


def resolve(name: str) -> IntegratorInfo:
    """The :class:`IntegratorInfo` for a name or alias; ValueError listing the choices otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"integrator: expected a method name (one of {sorted(INTEGRATORS)}), got {name!r}")
    key = _ALIASES.get(name, name)
    if key not in INTEGRATORS:
        raise ValueError(f"integrator: unknown name {name!r}; choose one of {sorted(INTEGRATORS)}")
    return INTEGRATORS[key]



def fixed_step_name(integrator, backend: str = "torch") -> str:
    """The resolved name of a fixed-step explicit method (``semi_implicit_euler`` or ``rk4``);
    ValueError naming ``integrator`` for another method (``backend`` names who runs only those)."""
    name = resolve(integrator).name
    if name not in EXPLICIT:
        raise ValueError(f"integrator: {integrator!r} is not available in the {backend} backend; "
                         "use 'semi_implicit_euler' or 'rk4'")
    return name


def uses_numba(backend: str, info: IntegratorInfo) -> bool:
    """Whether a step of ``info``'s method with ``backend`` runs the numba kernels (the fixed-step
    explicit methods; the adaptive ones integrate in scipy)."""
    return not info.adaptive and numba_backend(backend)


#: what ``backend="numpy"`` says: the NumPy equations are the repository's test oracle, not a backend
NUMPY_REMOVED = ("'numpy' is no longer a backend: every fixed step, projection, acceleration and contact "
                 "force runs on the numba kernels (the NumPy reference equations are the test oracle "
                 "tests/oracle_numpy.py of the repository); choose 'auto' or 'numba'")


def numba_backend(backend: str) -> bool:
    """True for ``backend`` "auto" or "numba" (the numba kernels); ValueError naming ``backend``
    for another name ("numpy": the test oracle, :data:`NUMPY_REMOVED`)."""
    if backend == "numpy":
        raise ValueError(f"backend: {NUMPY_REMOVED}")
    if backend not in ("auto", "numba"):
        raise ValueError(f"backend: unknown {backend!r}; choose 'auto' or 'numba'")
    return True
