"""The device env's record (:class:`TorchRecord`, a part of
:class:`~tensegrity_gym.envs.torch_shell.TorchTaskVectorEnv`): the task's ``STATE`` and
``CONSTANTS`` (:mod:`tensegrity_gym.tasks.state`) as device tensors, their rows copied after a
host reset, the per-copy physics parameters copied from the host task, and the record's
parameter writer. SI units."""
from __future__ import annotations

import numpy as np

from ..backends.torch.model import torch_module
from ..core.param_table import PARAMS, env_params

__all__ = ["TorchRecord"]

#: env parameter name -> its row of the parameter table (write_params)
ENV_PARAMS = env_params()


class TorchRecord:
    """The host <-> device copies of a device env (a mixin: the env holds ``task``, ``device``,
    ``dtype``)."""

    def _T(self, x):
        torch = torch_module()
        return torch.as_tensor(np.array(x, dtype=float), dtype=self.dtype, device=self.device)

    def _device_array(self, field, x):
        """The device copy of the host array ``x`` of the record field ``field`` (None stays None)."""
        if x is None:
            return None
        torch = torch_module()
        if field.kind == "bool":
            return torch.as_tensor(np.asarray(x, dtype=bool), device=self.device)
        if field.kind == "int":
            return torch.as_tensor(np.asarray(x, dtype=np.int64), device=self.device)
        return self._T(x if field.nan is None else np.nan_to_num(x, nan=field.nan))

    def _init_state(self) -> None:
        """The record: a device tensor per field of the task's ``STATE`` and ``CONSTANTS``; then
        the physics' own arrays (``_init_device``)."""
        for f in self.task.STATE + self.task.CONSTANTS:
            setattr(self, f.name, self._device_array(f, f.read(self.task)))
        self._init_device()

    def _init_device(self) -> None:
        """The device arrays the env's physics and device resets need beyond the record."""

    def _upload_rows(self, it, idx) -> None:
        """Rows ``idx`` (host) of the task's state into rows ``it`` (device) of the record."""
        for f in self.task.STATE:
            getattr(self, f.name)[it] = self._device_array(f, f.read(self.task)[idx])

    def write_params(self, rows, values: dict) -> None:
        """The record's writer of per-copy physics parameters: copies ``rows`` take ``values``
        (env parameter name -> (r, ...) tensor) in their ``Params`` field."""
        for name, v in values.items():
            row = ENV_PARAMS.get(name)
            if row is None or row.group != "physics" or self._params is None or row.field not in self._params:
                raise ValueError(f"write_params: {name!r} is not a per-copy physics parameter of this env")
            self._params[row.field][rows] = v.to(self.dtype)

    def _upload_domain(self, idx) -> None:
        """Copy the host task's parameter rows to the device: all (``idx`` None) or rows ``idx``
        (a randomised domain after a reset)."""
        task = self.task
        if idx is not None and not task.draws_physics:
            return
        torch = torch_module()
        idx_t = None if idx is None else torch.as_tensor(idx, dtype=torch.int64, device=self.device)

        def rows(cur, host):      # the whole array, or rows idx written into the device tensor
            if idx_t is None or cur is None or cur.shape[0] != host.shape[0] or host.shape[0] == 1:
                return self._T(host)
            cur[idx_t] = self._T(host[idx])
            return cur

        def put(name, host):
            setattr(self, name, None if host is None else rows(getattr(self, name, None), host))
        prm = task.params
        if prm is None:
            self._params = None
        else:
            self._params = getattr(self, "_params", None) or {}
            # the Params fields the env parameters write (and those derived from them); a field whose
            # term the equations skip where it is 0 only where it may be non-zero
            fields = [r.field for r in PARAMS if r.group == "physics" and (r.randomizable or r.write == "derived")
                      and (not r.skip_zero or prm.may_be_nonzero(r.field) or task.model.nominal.may_be_nonzero(r.field))]
            for f in fields:
                self._params[f] = rows(self._params.get(f), np.asarray(getattr(prm, f), float))
        put("_rest_offset", None if task.rest_offset is None else np.asarray(task.rest_offset, float))
        put("_contact_prm", getattr(task, "_contact_prm", None))
        if getattr(task, "terrain_contact", None) is not None:   # every part's contact parameters, per copy
            put("_terrain_prm", task.terrain_prm)
        act = task.actuation
        put("_max_rate", act.rate_rows)
        put("_max_accel", None if act.accel_rows is None else np.asarray(act.accel_rows, float)[:, None])
        if hasattr(task, "_mass_frac"):
            mf = np.asarray(task._mass_frac, float)
            put("_mass_frac", mf if mf.ndim == 2 else mf[None])
