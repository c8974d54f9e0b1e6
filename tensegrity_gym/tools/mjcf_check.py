"""Free flight of a MuJoCo model (MJCF) against its import here: how far the structure that
:func:`tensegrity_gym.io.mjcf.from_mjcf` reads moves away from MuJoCo running the file itself.

SI units (m, s). Both sides run without gravity and without contact, with RK4 at the same step
``dt``, from the file's initial pose at rest (MuJoCo's actuators at zero control). MuJoCo's node
points are the imported nodes carried by its bodies (:attr:`ImportReport.node_frames
<tensegrity_gym.core.mjcf_report.ImportReport>`), so the difference measures what the import
changes (sites mapped onto the rod axes, springs made tension-only, parallel tendons merged),
not the integrators. Needs the ``mujoco`` package.
"""
from __future__ import annotations

import math
import os

import numpy as np

from ..core.model import compile_model, initial_state
from ..core.mjcf_import import from_mjcf
from ..physics.geometry import node_positions
from ..physics.rollout import simulate

__all__ = ["free_flight"]


def free_flight(source, duration: float = 0.2, dt: float = 1e-4, samples: int = 20) -> dict:
    """``{"error": m, "moved": m, "structure", "report"}``: the largest distance between a node
    here and the same node in MuJoCo over ``samples`` equally spaced times up to ``duration`` s of
    free flight, and the largest distance a node moved in MuJoCo (the size of the motion).
    ``source``: an MJCF path or XML text."""
    import mujoco
    for name, v in (("duration", duration), ("dt", dt)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a positive number of seconds, got {v!r}")
    if not (isinstance(samples, int) and samples >= 1):
        raise ValueError(f"samples: must be an integer >= 1, got {samples!r}")
    every = max(1, int(round(duration / dt / samples)))
    s, report = from_mjcf(source)
    s = s.replace(gravity=None)
    text = isinstance(source, str) and source.lstrip().startswith("<")
    M = mujoco.MjModel.from_xml_string(source) if text else mujoco.MjModel.from_xml_path(os.fspath(source))
    M.opt.gravity[:] = 0.0
    M.opt.timestep, M.opt.integrator = dt, mujoco.mjtIntegrator.mjINT_RK4
    M.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    D = mujoco.MjData(M)
    frames = [(None if b is None else mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_BODY, b), np.asarray(p, float))
              for b, p in report.node_frames]
    theirs = []
    for _ in range(samples):
        mujoco.mj_step(M, D, every)
        mujoco.mj_forward(M, D)
        theirs.append([p if b is None else D.xpos[b] + D.xmat[b].reshape(3, 3) @ p for b, p in frames])
    model = compile_model(s)
    _, q, _ = simulate(model, initial_state(model), dt, every * samples, "rk4", record_every=every)
    ours = np.array([node_positions(model, qk)[0] for qk in q[1:]])
    theirs = np.array(theirs)
    return {"error": float(np.abs(ours - theirs).max()), "moved": float(np.abs(theirs - s.nodes).max()),
            "structure": s, "report": report}
