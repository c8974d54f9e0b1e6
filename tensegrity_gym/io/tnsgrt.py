"""Import structures from tnsgrt (M. de Oliveira's tensegrity design library, MIT licence).

:func:`from_tnsgrt` reads tnsgrt's data model **without importing tnsgrt** (duck typing), so it
works on a tnsgrt object, on the same data as a plain dict, or on a JSON file of that dict.
tnsgrt's layout (version 0.6)::

    nodes               3 x n array (m)
    members             2 x M int array (node indices of each member)
    member_tags         {"bar": int indices, "string": int indices, ...}
    member_properties   table (pandas DataFrame, or a dict of columns / a list of row dicts) with
                        columns "stiffness" (N/m), "rest_length" (m), "mass" (kg), "lambda_"
                        (force density, N/m), "modulus" (Pa), "radius", "inner_radius" (m), ...
    node_properties     table with a "constraint" column: None, or a NodeConstraint whose
                        ``normal`` (p x 3 or 3 x p) spans the constrained directions
    label               name

Conversion (SI units on both sides):

* nodes: transposed to (n, 3); bars and strings from ``member_tags`` (members tagged neither are
  refused, with their indices);
* bar masses from ``mass`` (tnsgrt's default 1 kg);
* string stiffness and rest length: tnsgrt keeps ``stiffness = 0`` until
  ``update_member_properties("stiffness")`` is called; then it is ``E A / L`` and
  ``rest_length = L (1 - lambda_ / stiffness)``. Where a string's stiffness is 0 this importer
  applies the same formula from ``modulus``, ``radius``, ``inner_radius`` and ``lambda_``
  (steel cables are very stiff: 1e6-1e8 N/m, which needs a small time step; pass
  ``stiffness=`` to override). A string whose rest length comes out negative is refused;
* node constraints: a NodeConstraint with ``normal`` R (rows or columns spanning the constrained
  directions; ``dof = 0`` means pinned) becomes ``node_constraints[i] = R`` (``D n = D n0``);
* nodes on no bar become fixed anchors in this package (tnsgrt's statics has no such notion).

tnsgrt 0.6 itself does not import under NumPy 2 (it uses ``np.float_`` at import time) and needs
cvxpy. To build structures with it under NumPy 2, add the alias before importing it::

    import numpy as np
    if not hasattr(np, "float_"):
        np.float_ = np.float64          # NumPy-2 shim for tnsgrt 0.6
    from tnsgrt.prism import Prism
    s = tensegrity_gym.io.tnsgrt.from_tnsgrt(Prism(3, calculate_equilibrium=True))

There is no ``Tower`` class in tnsgrt 0.6: towers are built from prisms (``Structure.merge``,
``add_members``); any such structure converts like a prism.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core.checks import read_bounded
from ..core.structure import MAX_FILE_BYTES, Structure, StructureError

__all__ = ["from_tnsgrt", "to_tnsgrt_dict"]

_COLUMNS = ("stiffness", "rest_length", "mass", "lambda_", "modulus", "radius", "inner_radius")
_DEFAULTS = {"stiffness": 0.0, "rest_length": 0.0, "mass": 1.0, "lambda_": 0.0, "modulus": 200e9,
             "radius": 0.01, "inner_radius": 0.0}


def _get(obj: Any, key: str, default=None):
    if isinstance(obj, Mapping):
        return obj.get(key, default)
    return getattr(obj, key, default)


def _column(table: Any, name: str, count: int, where: str) -> np.ndarray:
    """Column ``name`` of a DataFrame-like table, a dict of columns or a list of row dicts."""
    if table is None:
        return np.full(count, _DEFAULTS[name])
    if isinstance(table, (list, tuple)):
        if len(table) != count:
            raise StructureError(f"tnsgrt {where}: expected {count} rows, got {len(table)}")
        vals = [row.get(name, _DEFAULTS[name]) if isinstance(row, Mapping) else _DEFAULTS[name] for row in table]
    else:
        try:
            col = table[name]
        except (KeyError, IndexError, TypeError):
            return np.full(count, _DEFAULTS[name])
        vals = list(getattr(col, "values", col))
    out = np.empty(count)
    if len(vals) != count:
        raise StructureError(f"tnsgrt {where}[{name!r}]: expected {count} values, got {len(vals)}")
    for i, v in enumerate(vals):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise StructureError(f"tnsgrt {where}[{name!r}] of member {i}: expected a number, got {v!r}")
        out[i] = float(v)
        if not math.isfinite(out[i]):
            raise StructureError(f"tnsgrt {where}[{name!r}] of member {i}: {v!r} is not finite")
    return out


def _constraints(node_props: Any, n: int, nodes: np.ndarray) -> dict:
    if node_props is None:
        return {}
    if isinstance(node_props, (list, tuple)):
        col = [row.get("constraint") if isinstance(row, Mapping) else None for row in node_props]
    else:
        try:
            col = node_props["constraint"]
        except (KeyError, IndexError, TypeError):
            return {}
        col = list(getattr(col, "values", col))
    if len(col) != n:
        raise StructureError(f"tnsgrt node_properties['constraint']: expected {n} values, got {len(col)}")
    out = {}
    for i, c in enumerate(col):
        if c is None or (isinstance(c, float) and math.isnan(c)):
            continue
        dof = _get(c, "dof", None)
        normal = _get(c, "normal", None)
        if normal is None and isinstance(c, (list, tuple, np.ndarray)):
            normal = c
        if dof == 0 or normal is None:
            out[i] = np.eye(3)
            continue
        R = np.asarray(normal, float)
        if R.ndim == 1:
            R = R[None, :]
        if R.shape[1] != 3 and R.shape[0] == 3:
            R = R.T                      # tnsgrt stores 3 x p
        elif R.shape == (3, 3) and dof is not None and dof > 0 and np.linalg.matrix_rank(R) == 3:
            R = R[: 3 - int(dof)]
        if R.ndim != 2 or R.shape[1] != 3:
            raise StructureError(f"tnsgrt constraint of node {i}: normal has shape {R.shape}, expected (p, 3)")
        out[i] = R
    return out


def to_tnsgrt_dict(obj: Any) -> dict:
    """The plain-dict form of a tnsgrt structure (JSON-serialisable; constraints as normals)."""
    nodes = np.asarray(_get(obj, "nodes"), float)
    members = np.asarray(_get(obj, "members"))
    tags = {k: np.asarray(v).astype(int).tolist() for k, v in (_get(obj, "member_tags") or {}).items()}
    M = members.shape[1] if members.ndim == 2 else 0
    props = {c: _column(_get(obj, "member_properties"), c, M, "member_properties").tolist() for c in _COLUMNS}
    cons = _constraints(_get(obj, "node_properties"), nodes.shape[1], nodes.T)
    return {"label": _get(obj, "label"), "nodes": nodes.tolist(), "members": members.astype(int).tolist(),
            "member_tags": tags, "member_properties": props,
            "node_properties": {"constraint": [cons[i].tolist() if i in cons else None
                                               for i in range(nodes.shape[1])]}}


def from_tnsgrt(obj_or_path: Any, *, stiffness=None, bar_mass=None, damping=0.0, gravity=None,
                name: str | None = None) -> Structure:
    """A :class:`Structure` from a tnsgrt structure, its dict form or a JSON file of it.

    Keyword overrides (SI units): ``stiffness`` (N/m, number or per string; default: tnsgrt's,
    or E A / L), ``bar_mass`` (kg; default: tnsgrt's ``mass``), ``damping`` (N s/m),
    ``gravity`` ((3,) m/s^2), ``name``. Errors name the field, the member and the value.
    """
    obj = obj_or_path
    if isinstance(obj, (str, os.PathLike)):
        path = Path(obj)
        try:
            obj = json.loads(read_bounded(path, MAX_FILE_BYTES, "tnsgrt structure file"))
        except json.JSONDecodeError as exc:
            raise StructureError(f"{path}: not valid JSON ({exc})") from None
        except (OSError, ValueError) as exc:      # not found, unreadable, a FIFO or device, too large, not UTF-8
            raise StructureError(f"{path}: cannot read ({exc})") from None
        if not isinstance(obj, dict):
            raise StructureError(f"{path}: top level must be a JSON object (tnsgrt structure dict)")
    raw_nodes = _get(obj, "nodes")
    raw_members = _get(obj, "members")
    if raw_nodes is None or raw_members is None:
        raise StructureError("tnsgrt structure: needs 'nodes' (3 x n) and 'members' (2 x m)")
    try:
        nodes = np.asarray(raw_nodes, float)
        members = np.asarray(raw_members, float)
    except (TypeError, ValueError) as exc:
        raise StructureError(f"tnsgrt nodes/members: not numeric arrays ({exc})") from None
    if nodes.ndim != 2 or nodes.shape[0] != 3:
        raise StructureError(f"tnsgrt nodes: expected a 3 x n array, got shape {nodes.shape}")
    if members.ndim != 2 or members.shape[0] != 2:
        raise StructureError(f"tnsgrt members: expected a 2 x m array, got shape {members.shape}")
    if not np.all(members == np.round(members)):
        raise StructureError("tnsgrt members: node indices must be integers")
    members = members.astype(np.int64)
    M = members.shape[1]
    tags = _get(obj, "member_tags") or {}
    bar_idx = np.asarray(tags.get("bar", []), dtype=np.int64).ravel()
    str_idx = np.asarray(tags.get("string", []), dtype=np.int64).ravel()
    for nm, idx in (("bar", bar_idx), ("string", str_idx)):
        if idx.size and (idx.min() < 0 or idx.max() >= M):
            raise StructureError(f"tnsgrt member_tags[{nm!r}]: index out of range 0..{M - 1}")
    both = np.intersect1d(bar_idx, str_idx)
    if both.size:
        raise StructureError(f"tnsgrt member_tags: members {both.tolist()} are tagged both bar and string")
    untagged = np.setdiff1d(np.arange(M), np.union1d(bar_idx, str_idx))
    if untagged.size:
        raise StructureError(f"tnsgrt member_tags: members {untagged.tolist()} are neither 'bar' nor 'string'")
    props = _get(obj, "member_properties")
    col = {c: _column(props, c, M, "member_properties") for c in _COLUMNS}
    L = np.linalg.norm(nodes[:, members[1]] - nodes[:, members[0]], axis=0)
    # strings: stiffness and rest length
    k = col["stiffness"][str_idx].copy()
    rest = col["rest_length"][str_idx].copy()
    lam = col["lambda_"][str_idx]
    need = k <= 0
    if np.any(need):
        area = np.pi * (col["radius"][str_idx] ** 2 - col["inner_radius"][str_idx] ** 2)
        k[need] = (col["modulus"][str_idx] * area / np.where(L[str_idx] > 0, L[str_idx], np.inf))[need]
        rest[need] = (L[str_idx] * (1.0 - lam / np.where(k > 0, k, np.inf)))[need]
    if stiffness is not None:
        k_new = np.broadcast_to(np.asarray(stiffness, float), k.shape).copy()
        # keep tnsgrt's prestress (the force density lambda_) with the new stiffness
        rest = L[str_idx] * (1.0 - lam / np.where(k_new > 0, k_new, np.inf))
        k = k_new
    for i, (kk, r0) in enumerate(zip(k, rest)):
        if not (math.isfinite(r0) and r0 >= 0):
            raise StructureError(f"tnsgrt string {int(str_idx[i])}: rest length {r0} m is negative "
                                 f"(force density {lam[i]} N/m exceeds its stiffness {kk} N/m)")
    mass = col["mass"][bar_idx] if bar_mass is None else bar_mass
    cons = _constraints(_get(obj, "node_properties"), nodes.shape[1], nodes.T)
    label = name or _get(obj, "label") or \
        ("tnsgrt" if isinstance(obj, Mapping) else f"tnsgrt {type(obj).__name__}")
    return Structure(nodes.T, members[:, bar_idx].T, members[:, str_idx].T, bar_mass=mass, stiffness=k,
                     rest_length=rest, damping=damping, gravity=gravity, node_constraints=cons,
                     name=str(label))
