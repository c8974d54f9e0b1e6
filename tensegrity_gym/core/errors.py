"""Errors and warnings of the structure and the simulation (a structure too large for memory:
:class:`~tensegrity_gym.core.sizing.StructureTooLarge`)."""
from __future__ import annotations

__all__ = ["StructureError", "SimulationDiverged", "EvaluationBudgetExceeded", "StabilityWarning"]


class StructureError(ValueError):
    """Raised when a structure is not a valid class-1 tensegrity."""


class SimulationDiverged(FloatingPointError):
    """Raised when the state stops being finite; the message names time and cause."""


class EvaluationBudgetExceeded(RuntimeError):
    """An adaptive method needed more right-hand-side evaluations than ``max_evaluations``
    (tolerances too tight for the span, or a very stiff structure): raised instead of running on."""


class StabilityWarning(UserWarning):
    """``dt`` is above the estimated stability limit of an explicit integrator."""

