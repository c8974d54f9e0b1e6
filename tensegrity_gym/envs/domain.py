"""The robot's physical parameters per env copy: fixed (``params=``) and randomised at every
reset (``randomize=``), for every task, single and vector env alike (SI units).

===========================  ============  ======  =====================================================
name                         per           unit    ``randomize={name: s}`` draws, per copy at reset
===========================  ============  ======  =====================================================
``rod_mass``                 rod           kg      nominal x U(1 - s, 1 + s), each rod independently
                                                   (the rod's mass distribution keeps its shape)
``stiffness``                string        N/m     nominal x U(1 - s, 1 + s), each string
``damping``                  string        N s/m   nominal x U(1 - s, 1 + s), each string
``node_damping``             node          N s/m   nominal x U(1 - s, 1 + s), each node
``gravity``                  (3,) vector   m/s^2   nominal x U(1 - s, 1 + s), one factor (magnitude)
``rest_length_offset``       string        m       nominal + U(-s, s), each string (absolute): the
                                                   cable's true rest length minus the commanded one
``friction``                 copy          1       nominal x U(1 - s, 1 + s)   (tasks with ground contact)
``ground_stiffness``         copy          N/m     nominal x U(1 - s, 1 + s)   (normal contact stiffness)
``ground_damping``           copy          s/m     nominal x U(1 - s, 1 + s)   (Hunt-Crossley damping)
``max_cable_speed``          actuated      m/s     nominal x U(1 - s, 1 + s), each actuated cable
                                                   (rest-length actions; N/(m s) in force-density mode)
``max_cable_acceleration``   copy          m/s^2   nominal x U(1 - s, 1 + s)   (the motor model)
===========================  ============  ======  =====================================================

``params={name: value}`` fixes a parameter for every copy: a number (every item) or one value per
item (a list of k rods, m strings, n nodes, na actuated cables, or the 3 gravity components),
absolute SI values; a randomised parameter is then drawn around the fixed value. Relative spreads
must be in [0, 1) (a positive value stays positive); absolute spreads >= 0. At each reset a copy
draws from a child generator spawned from its own (``np_random.spawn(1)``; env i of a vector env
has its own ``np_random``), name by name in alphabetical order and item by item. Spawning draws
nothing from the parent stream, so the task's own reset draws (noise, targets, goals) are the
same as with the values fixed, and a vector env equals N single envs built with ``params=`` set
to the values each copy reported in ``info["params"]``.
With neither argument nothing is drawn and no per-copy code runs (defaults are bit-identical).
"""
from __future__ import annotations

import numpy as np


from ..core.param_table import DomainSpec, domain_specs, env_params
from ..tasks.randomization import draw_count, draw_range, values_from_draws

__all__ = ["SPECS", "Domain", "physics_nominal", "container_nominal", "write_copies"]

Spec = DomainSpec
#: env parameter name -> what Domain reads of its row (a view of tensegrity_gym.core.param_table)
SPECS: dict[str, DomainSpec] = domain_specs()


def _number_array(value, name: str, what: str) -> np.ndarray:
    if isinstance(value, (str, bytes, bool, np.bool_)) or (
            isinstance(value, (list, tuple)) and any(isinstance(v, (str, bytes, bool)) for v in value)):
        raise ValueError(f"{what}[{name!r}]: expected a number or a list of numbers, got {value!r:.80}")
    try:
        return np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what}[{name!r}]: expected a number or a list of numbers, got {value!r:.80}") from None


class Domain:
    """Per-copy values of the parameters named in ``params`` / ``randomize`` (see the module doc).

    ``nominal``: name -> the task's nominal value (per-item array) for every name the task
    supports. After :meth:`sample`, ``values[name]`` is (B,) + item shape."""

    def __init__(self, nominal: dict[str, np.ndarray], num_envs: int, params: dict | None = None,
                 randomize: dict | None = None):
        self.num_envs = int(num_envs)
        self.specs = SPECS = domain_specs()   # read at construction: the table's current rows
        params = {} if params is None else params
        randomize = {} if randomize is None else randomize
        for arg, d in (("params", params), ("randomize", randomize)):
            if not isinstance(d, dict):
                raise ValueError(f"{arg}: expected a dict {{name: value}}, got {type(d).__name__}")
            for name in d:
                if name not in SPECS:
                    raise ValueError(f"{arg}: unknown parameter {name!r}; known: {sorted(SPECS)}")
                if name not in nominal:
                    raise ValueError(f"{arg}: {name!r} is not a parameter of this task (it has "
                                     f"{sorted(nominal)})")
        self.base: dict[str, np.ndarray] = {}
        for name, v in params.items():
            nom = np.asarray(nominal[name], float)
            a = _number_array(v, name, "params")
            if a.ndim == 0:
                a = np.full(nom.shape, float(a))
            if a.shape != nom.shape:
                raise ValueError(f"params[{name!r}]: expected a number or {nom.shape[0] if nom.ndim else 1} values "
                                 f"(one per {SPECS[name].per}), got shape {a.shape}")
            sp = SPECS[name]
            rule = sp.valid
            ok = np.isfinite(a) & {"positive": a > 0, "nonnegative": a >= 0, "finite": True}[rule]
            if not np.all(ok):
                i = int(np.flatnonzero(~ok.reshape(-1))[0])
                need = {"positive": "> 0", "nonnegative": ">= 0", "finite": "finite"}[rule]
                unit = f" {sp.unit}" if sp.unit else ""
                raise ValueError(f"params[{name!r}]: {sp.per} {i}: must be {need}{unit}, "
                                 f"got {float(a.reshape(-1)[i])!r}")
            self.base[name] = a
        self.spread: dict[str, float] = {}
        for name, s in sorted(randomize.items()):
            try:
                if isinstance(s, (str, bytes)):   # a number, not text (as params and every other argument)
                    raise TypeError
                s = float(s)
            except (TypeError, ValueError):
                raise ValueError(f"randomize[{name!r}]: expected a number (spread), got {s!r:.80}") from None
            if isinstance(randomize[name], bool) or not np.isfinite(s) or s < 0 or (not SPECS[name].absolute and s >= 1):
                rng = "a finite number >= 0 (m)" if SPECS[name].absolute else "in [0, 1) (relative)"
                raise ValueError(f"randomize[{name!r}]: spread must be {rng}, got {randomize[name]!r}")
            self.spread[name] = s
        for name in self.spread:
            self.base.setdefault(name, np.asarray(nominal[name], float).copy())
        self.names = sorted(self.base)
        self.values = {name: np.repeat(self.base[name][None], self.num_envs, axis=0) for name in self.names}

    @property
    def enabled(self) -> bool:
        return bool(self.names)

    @property
    def randomized(self) -> bool:
        return bool(self.spread)

    def sample(self, idx: np.ndarray, rngs) -> None:
        """Draw new values for copies ``idx`` from their generators ``rngs`` (one per copy)."""
        for j, i in enumerate(idx):
            rng = rngs[j].spawn(1)[0]   # a child stream: the task's own draws are those of fixed values
            for name, s in self.spread.items():      # sorted by name
                base, spec = self.base[name], self.specs[name]
                lo, hi = draw_range(spec, s)
                x = rng.uniform(lo, hi, draw_count(spec, base))
                self.values[name][i] = values_from_draws(spec, base, x[None])[0]

    def report(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        """name -> (len(idx),) + item values of copies ``idx`` (what ``info["params"]`` holds)."""
        return {name: self.values[name][idx].copy() for name in self.names}


def physics_nominal(model) -> dict[str, np.ndarray]:
    """Env parameter name -> nominal value of the ``"physics"`` rows of the parameter table, read
    from the compiled ``model``: an ``"elastic"`` row the structure's own value (also on the
    force-density-actuated strings), an ``"offset"`` row zeros, any other its ``Params`` field."""
    out = {}
    for name, row in env_params().items():
        if row.group != "physics":
            continue
        if row.write == "elastic":
            out[name] = getattr(model.structure, row.field)
        elif row.write == "offset":
            out[name] = np.zeros(np.shape(getattr(model, row.field)))
        else:
            out[name] = getattr(model.nominal, row.field)[0]
    return out


def container_nominal(group: str, container) -> dict[str, np.ndarray]:
    """Env parameter name -> nominal value (an array copy) of the rows of ``group`` (``"contact"``:
    a ``GroundContact``; ``"actuation"``: an ``Actuation``), read from the container's fields;
    a field the container does not have (None: no motor model) is not a parameter of the task."""
    out = {}
    for name, row in env_params().items():
        value = getattr(container, row.field, None) if row.group == group else None
        if value is not None:
            out[name] = np.array(value, dtype=float)
    return out


def write_copies(sink, rows, values: dict) -> None:
    """Write per-copy parameter values into their containers: the one writer of the single env,
    the NumPy vector env and the torch vector env (host and device resets).

    ``values``: env parameter name -> (len(rows), ...) values of copies ``rows`` (NumPy arrays or
    torch tensors). Each name goes where its row of the parameter table says: a ``"physics"``
    row into the ``Params`` field (``"elastic"``: 0 on the force-density-actuated strings;
    ``"offset"``: the model's nominal field plus the value, the value also kept as the copies'
    offset), a ``"contact"`` row into its contact parameter column, an ``"actuation"`` row into
    its ``Actuation`` limit. ``sink`` holds the containers and provides ``nominal(field)``,
    ``no_elastic_part`` (m,) bool, ``zero_where(mask, v)``, ``write_physics(rows, fields,
    offsets)``, ``write_contact(rows, columns)`` and ``write_actuation(rows, fields)`` (each
    dict: field -> values)."""
    specs = env_params()
    physics, offsets, contact, actuation = {}, {}, {}, {}
    for name, v in values.items():
        row = specs[name]
        if row.group == "physics":
            if row.write == "elastic":
                v = sink.zero_where(sink.no_elastic_part, v)
            elif row.write == "offset":
                offsets[row.field] = v
                v = sink.nominal(row.field) + v
            physics[row.field] = v
        elif row.group == "contact":
            contact[row.field] = v
        else:
            actuation[row.field] = v
    if physics or offsets:
        sink.write_physics(rows, physics, offsets)
    if contact:
        sink.write_contact(rows, contact)
    if actuation:
        sink.write_actuation(rows, actuation)
