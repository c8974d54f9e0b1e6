"""A task's state record, declared once for every shell that runs the task.

A task (:class:`~tensegrity_gym.envs.base.BatchedTask`) lists its per-copy state arrays in
``STATE`` and the arrays its step functions read but never write in ``CONSTANTS``, as
:class:`StateField` rows. Each shell holds one record with those names: the NumPy task is its
own record (NumPy arrays, attributes of the task), the torch device env
(:class:`~tensegrity_gym.envs.torch_shell.TorchTaskVectorEnv`) builds its record from the rows
(device tensors of the same names, copied from the task at construction and, row by row, after
each host reset). The task's step, observation and reset functions are written once over that
record (:mod:`tensegrity_gym.tasks.xp` operations), so a new piece of task state is one row here
and its updates once, not a second lifecycle per backend.

A record also offers, whatever the shell: ``com(q)`` (B, 3) the centres of mass (m) of the
robots ``q`` (B, k, 6); ``write_params(rows, {name: values})`` (the per-copy physics
parameters of copies ``rows``, such as a slope's gravity); ``terrain_height(x, y)`` (B, m) the
ground's height (m) under the points ``x``, ``y`` (B, m) m of each copy.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["StateField", "KINDS"]

#: the array kinds of a field: a float in the shell's dtype, a bool, an integer (int64 on torch)
KINDS = ("float", "bool", "int")


@dataclass(frozen=True)
class StateField:
    """One named array of a task's record, (B, ...) per copy for ``STATE``.

    ``name``: the record's attribute (the same in every shell); ``kind``: one of :data:`KINDS`;
    ``host``: the dotted attribute path on the NumPy task where it is not ``name`` (for example
    ``"cstate.anchor"``); ``nan``: the value NaN takes in the device copy (None: kept), for
    arrays whose unused entries are NaN on the host."""

    name: str
    kind: str = "float"
    host: str | None = None
    nan: float | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"StateField {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")

    def read(self, task):
        """The host task's array of this field."""
        obj = task
        for part in (self.host or self.name).split("."):
            obj = getattr(obj, part)
        return obj
