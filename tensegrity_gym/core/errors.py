"""Errors and warnings of the simulation (the structure's own errors live beside it:
:class:`~tensegrity_gym.core.structure.StructureError`,
:class:`~tensegrity_gym.core.sizing.StructureTooLarge`)."""
from __future__ import annotations

__all__ = ["SimulationDiverged", "EvaluationBudgetExceeded", "StabilityWarning"]


class SimulationDiverged(FloatingPointError):
    """Raised when the state stops being finite; the message names time and cause."""


class EvaluationBudgetExceeded(RuntimeError):
    """An adaptive method needed more right-hand-side evaluations than ``max_evaluations``
    (tolerances too tight for the span, or a very stiff structure): raised instead of running on."""


class StabilityWarning(UserWarning):
    """``dt`` is above the estimated stability limit of an explicit integrator."""

