"""The result of a system identification (:class:`SysIdResult`), its warning class and the
fittable fields with their units."""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..core.params import Params

#: fittable field -> what its items are (positive quantities, fitted in log space)
FITTABLE = {"stiffness": "string", "damping": "string", "mass": "rod", "node_damping": "node",
            "friction": "ground", "ground_stiffness": "ground", "ground_damping": "ground"}
_ALIASES = {"rod_mass": "mass", "bar_mass": "mass"}
_UNITS = {"stiffness": "N/m", "damping": "N s/m", "mass": "kg", "node_damping": "N s/m",
          "friction": "1", "ground_stiffness": "N/m", "ground_damping": "s/m"}
#: the ground contact's fittable fields -> the GroundContact field each one is (one value each:
#: Coulomb coefficient, normal stiffness N/m, Hunt-Crossley damping s/m)
CONTACT_FIELDS = {"friction": "friction", "ground_stiffness": "stiffness", "ground_damping": "damping"}
#: a fit misses the record when its RMS error is above MISFIT_NOISE x the record's noise AND above
#: MISFIT_MOTION x the record's motion (it explains less than 99 % of the motion's variance) AND
#: above MISFIT_FLOOR m (1 um, below any tracker's noise: round-off of a record without motion)
MISFIT_NOISE = 10.0
MISFIT_MOTION = 0.1
MISFIT_FLOOR = 1e-6


class SysIdWarning(UserWarning):
    """A fit did not converge or a parameter is not identifiable from the record."""


# ----------------------------------------------------------------------------- result
@dataclass
class SysIdResult:
    """Outcome of :func:`tensegrity_gym.tools.sysid.identify` (SI units).

    ``values[f]``, ``initial[f]``, ``std_errors[f]``, ``identifiable[f]``: arrays over the items
    ``items[f]`` (string / rod / node indices) of each fitted field ``f``. ``scale[f]`` and
    ``scale_std_errors[f]``: the fitted factor of field ``f`` (``mode="scale"`` only).
    ``rms_m``: RMS node error over every observed coordinate after the fit (``rms_initial_m``:
    with the initial values, window states fitted). ``converged``: the optimiser met its
    tolerances and every window's state fit converged. ``at_bound[f]``: the items whose value
    ran to the search bound (a factor of e^5 = 148 from its starting value): the record does not
    fix them within that range, so they are also not identifiable (infinite standard error).
    ``noise_m``: the position noise the record shows (RMS second difference of consecutive
    samples over sqrt(6); an upper bound), ``motion_rms_m``: the RMS motion of the tracked
    nodes about their mean in each window. ``misfit``: ``rms_m`` is above
    :data:`MISFIT_NOISE` x ``noise_m``, above :data:`MISFIT_MOTION` x ``motion_rms_m`` and above
    :data:`MISFIT_FLOOR` (1 um): the
    model does not explain the record (another structure, ground, gravity or actuation than
    the recording's). ``ok``: converged, every fitted parameter identifiable and none at the
    search bound, and no misfit. ``params``: the fitted :class:`Params` (one row). ``contact``: the
    fitted :class:`~tensegrity_gym.physics.contact.GroundContact` of a fit with ground contact
    (None without); its fitted values are also in ``values`` under ``friction``,
    ``ground_stiffness`` and ``ground_damping`` (item 0)."""

    fields: tuple
    mode: str
    items: dict
    values: dict
    initial: dict
    std_errors: dict
    rel_std_errors: dict
    identifiable: dict
    scale: dict
    scale_std_errors: dict
    converged: bool
    rms_m: float
    rms_initial_m: float
    max_error_m: float
    message: str
    warnings: list
    n_windows: int
    samples_per_window: int
    window_s: float
    sample_dt_s: float
    dt_s: float
    n_substeps: int
    integrator: str
    n_observations: int
    n_state_unknowns: int
    nfev: int
    njev: int
    wall_s: float
    params: Params = field(repr=False, default=None)
    contact: object = field(repr=False, default=None)
    _plot: dict = field(repr=False, default=None)
    at_bound: dict = field(default_factory=dict)
    noise_m: float = 0.0
    motion_rms_m: float = 0.0
    misfit: bool = False

    @property
    def ok(self) -> bool:
        return bool(self.converged and all(np.all(v) for v in self.identifiable.values())
                    and not any(np.any(v) for v in self.at_bound.values()) and not self.misfit)

    def to_dict(self) -> dict:
        """JSON-ready summary (infinite standard errors as None)."""
        def arr(a):
            return [None if not np.isfinite(x) else float(x) for x in np.asarray(a, float)]
        out = {"ok": self.ok, "converged": self.converged, "message": self.message, "warnings": list(self.warnings),
               "mode": self.mode, "fields": list(self.fields), "units": {f: _UNITS[f] for f in self.fields},
               "items": {f: [int(i) for i in v] for f, v in self.items.items()},
               "values": {f: arr(v) for f, v in self.values.items()},
               "initial": {f: arr(v) for f, v in self.initial.items()},
               "std_errors": {f: arr(v) for f, v in self.std_errors.items()},
               "rel_std_errors": {f: arr(v) for f, v in self.rel_std_errors.items()},
               "identifiable": {f: [bool(x) for x in v] for f, v in self.identifiable.items()},
               "at_bound": {f: [bool(x) for x in v] for f, v in self.at_bound.items()},
               "rms_m": self.rms_m, "rms_initial_m": self.rms_initial_m, "max_error_m": self.max_error_m,
               "noise_m": self.noise_m, "motion_rms_m": self.motion_rms_m, "misfit": self.misfit,
               "n_windows": self.n_windows, "samples_per_window": self.samples_per_window,
               "window_s": self.window_s, "sample_dt_s": self.sample_dt_s, "dt_s": self.dt_s,
               "n_substeps": self.n_substeps, "integrator": self.integrator,
               "n_observations": self.n_observations, "n_state_unknowns": self.n_state_unknowns,
               "nfev": self.nfev, "njev": self.njev, "wall_s": self.wall_s,
               "gradient": "batched forward finite differences (per-copy Params)"}
        if self.contact is not None:     # the contact the fitted motion ran with (SI units)
            c = self.contact
            out["contact"] = {"friction": c.friction, "stiffness": c.stiffness, "damping": c.damping,
                              "tangential_stiffness": c.tangential_stiffness,
                              "tangential_damping": c.tangential_damping, "radius": c.radius, "height": c.height,
                              "exponent": c.exponent}
        if self.mode == "scale":
            out["scale"] = {f: float(v) for f, v in self.scale.items()}
            out["scale_std_errors"] = {f: (None if not np.isfinite(v) else float(v))
                                       for f, v in self.scale_std_errors.items()}
        return out

    def plot(self, path=None, nodes=None, max_nodes: int = 3):
        """Recorded (dots) vs fitted (lines, one segment per shooting window) displacements of
        node coordinates from their mean over the record, mm, for the ``max_nodes`` tracked nodes
        that move most (or the given ``nodes``), and the RMS error per sample. Writes a PNG to
        ``path`` if given; returns the matplotlib figure (Agg)."""
        import matplotlib
        if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        d = self._plot
        t, rec, fit, mask = d["t"], d["recorded"], d["fitted"], d["mask"]   # (W,K), (W,K,n,3) ...
        recn = np.where(mask[..., None], rec, np.nan)
        mean = np.nanmean(recn, axis=(0, 1))                                   # (n, 3)
        span = np.nan_to_num(np.nanmax(recn, axis=(0, 1)) - np.nanmin(recn, axis=(0, 1)), nan=-1.0).max(1)
        show = list(np.argsort(-span)[:max_nodes]) if nodes is None else [int(i) for i in nodes]
        fig, ax = plt.subplots(len(show) + 1, 1, figsize=(10, 2.2 * (len(show) + 1)), sharex=True, squeeze=False)
        ax = ax[:, 0]
        colors = ("tab:blue", "tab:orange", "tab:green")
        for a, i in zip(ax, show):
            for c in range(3):
                for w in range(t.shape[0]):
                    mk = mask[w, :, i]
                    a.plot(t[w][mk], 1e3 * (rec[w, mk, i, c] - mean[i, c]), ".", ms=2, color=colors[c],
                           label=f"{'xyz'[c]} recorded" if w == 0 else None)
                    a.plot(t[w], 1e3 * (fit[w, :, i, c] - mean[i, c]), "-", lw=1, color="k", alpha=0.7,
                           label="fitted" if (w == 0 and c == 0) else None)
            a.set_ylabel(f"node {i} [mm]")
        ax[0].legend(loc="upper right", ncol=4, fontsize=7)
        err = np.where(mask[..., None], fit - rec, np.nan)
        rms = np.sqrt(np.nanmean(err ** 2, axis=(2, 3)))
        for w in range(t.shape[0]):
            ax[-1].plot(t[w], rms[w] * 1e3, "-", color="tab:red", lw=1)
        ax[-1].set(ylabel="RMS error [mm]", xlabel="t [s]")
        ax[0].set_title(f"recorded vs fitted ({self.n_windows} shooting windows of {self.window_s:g} s); "
                        f"RMS {self.rms_m * 1e3:.3g} mm")
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=100)
        return fig
