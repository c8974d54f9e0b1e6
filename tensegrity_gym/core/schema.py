"""The rules of a structure file: the format's JSON Schema (``tensegrity_gym/structure.schema.json``, draft
2020-12) and the validator of the keywords it uses: :func:`validate_dict` raises
:class:`~tensegrity_gym.core.errors.StructureError` naming the key, the index and the value and
citing the schema's description of the key; the value checks of
:class:`~tensegrity_gym.core.structure.Structure` (numbers, ranges, per-item values) and the
strict JSON reader :func:`loads`.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import StructureError

__all__ = ["SCHEMA_PATH", "schema", "validate_dict", "loads"]

#: the JSON Schema (draft 2020-12) of the structure file format, shipped with the package
SCHEMA_PATH = Path(__file__).parent.parent / "structure.schema.json"   # package data of tensegrity_gym


# ---------------------------------------------------------------------- schema
_SCHEMA: dict | None = None
# keywords the validator below implements; annotations it ignores
_KEYWORDS = {"$ref", "type", "properties", "required", "additionalProperties", "propertyNames", "pattern",
             "items", "prefixItems", "minItems", "maxItems", "minimum", "maximum", "anyOf"}
_ANNOTATIONS = {"description", "title", "$schema", "$id", "$defs", "$comment"}
# the item a top-level key's first index counts
_ITEM = {"nodes": "node", "bars": "bar", "strings": "string", "bar_mass": "bar", "stiffness": "string",
         "rest_length": "string", "damping": "string", "velocities": "node", "mass_points": "bar"}
_TYPE_WORDS = {"null": "null", "boolean": "true/false", "object": "an object", "array": "a list",
               "number": "a number", "integer": "an integer", "string": "a string"}


def schema() -> dict:
    """The structure file's JSON Schema (a dict, loaded once from :data:`SCHEMA_PATH`)."""
    global _SCHEMA
    if _SCHEMA is None:
        s = json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))

        def audit(node):               # the validator must understand every keyword it is given
            if isinstance(node, dict):
                unknown = set(node) - _KEYWORDS - _ANNOTATIONS
                if unknown:
                    raise RuntimeError(f"{SCHEMA_PATH.name}: keyword(s) {sorted(unknown)} not implemented")
                for key, sub in node.items():
                    if key in ("properties", "$defs"):
                        for v in sub.values():
                            audit(v)
                    elif key in ("anyOf", "prefixItems"):
                        for v in sub:
                            audit(v)
                    elif key in ("items", "additionalProperties", "propertyNames"):
                        audit(sub)
        audit(s)
        _SCHEMA = s
    return _SCHEMA


def _describe(key) -> str:
    """The schema's description of a top-level key ('' if none)."""
    prop = schema()["properties"].get(key)
    return "" if prop is None else prop.get("description", "")


def _show(x) -> str:
    """A short rendering of a JSON value for messages."""
    if x is None:
        return "null"
    if isinstance(x, (bool, np.bool_)):
        return "true" if x else "false"
    if isinstance(x, str):
        return "the string " + json.dumps(x[:40] + ("..." if len(x) > 40 else ""))
    if isinstance(x, (int, np.integer)):
        s = str(int(x))
        return s if len(s) <= 20 else f"an integer of {len(s)} digits ({s[:4]}...{s[-2:]})"
    if isinstance(x, (float, np.floating)):
        r = repr(float(x))
        return r if len(r) <= 8 else f"{float(x):.6g}"
    if isinstance(x, (list, tuple, np.ndarray)):
        return f"a list of {len(x)} item{'s' if len(x) != 1 else ''}"
    if isinstance(x, Mapping):
        return f"an object with {len(x)} key{'s' if len(x) != 1 else ''}"
    return f"a {type(x).__name__}"


def _json_type(x) -> str:
    if x is None:
        return "null"
    if isinstance(x, (bool, np.bool_)):
        return "boolean"
    if isinstance(x, (int, np.integer)):
        return "integer"
    if isinstance(x, (float, np.floating)):
        return "number"
    if isinstance(x, str):
        return "string"
    if isinstance(x, (list, tuple, np.ndarray)):
        return "array"
    if isinstance(x, Mapping):
        return "object"
    return type(x).__name__


def _type_ok(x, t: str) -> bool:
    jt = _json_type(x)
    if t == "number":
        return jt in ("number", "integer")
    if t == "integer":
        return jt == "integer" or (jt == "number" and math.isfinite(x) and float(x).is_integer())
    return jt == t


def _loc(path) -> str:
    if not path:
        return "structure"
    s = str(path[0]) + "".join(f"[{p!r}]" if isinstance(p, str) else f"[{p}]" for p in path[1:])
    if len(path) > 1 and isinstance(path[1], int) and path[0] in _ITEM:
        s += f" ({_ITEM[path[0]]} {path[1]})"
    elif len(path) > 1 and path[0] == "node_constraints":
        s += f" (node {path[1]})"
    return s


class _SchemaError(Exception):
    def __init__(self, path, problem, value):
        super().__init__(problem)
        self.path, self.problem, self.value = list(path), problem, value


def _resolve(node: dict) -> dict:
    while "$ref" in node:
        ref = node["$ref"]
        if not ref.startswith("#/"):
            raise RuntimeError(f"{SCHEMA_PATH.name}: only local $ref supported, got {ref!r}")
        target: Any = schema()
        for part in ref[2:].split("/"):
            target = target[part]
        node = target
    return node


def _check(x, node: dict, path: list) -> None:
    node = _resolve(node)
    if "anyOf" in node:
        errors = []
        for branch in node["anyOf"]:
            try:
                _check(x, branch, path)
                return
            except _SchemaError as e:
                errors.append((_resolve(branch), e))
        # report the branch of x's own type (the most telling), else a type error
        same = [e for b, e in errors if "type" in b and _type_ok(x, b["type"])]
        if same:                       # the branch that got furthest (the last one on a tie)
            raise max(reversed(same), key=lambda e: len(e.path))
        kinds = []
        for b, _ in errors:
            w = _TYPE_WORDS.get(b.get("type"), "a value")
            if w not in kinds:
                kinds.append(w)
        raise _SchemaError(path, f"expected {' or '.join(kinds)}, got {_show(x)}", x)
    t = node.get("type")
    if t is not None:
        if not _type_ok(x, t):
            raise _SchemaError(path, f"expected {_TYPE_WORDS[t]}, got {_show(x)}", x)
        if t in ("number", "integer"):
            if isinstance(x, (float, np.floating)) and not math.isfinite(x):
                raise _SchemaError(path, f"expected a finite number, got {_show(x)}", x)
            lo, hi = node.get("minimum"), node.get("maximum")
            if lo is not None and x < lo:
                raise _SchemaError(path, f"{_show(x)} is below the accepted minimum {lo:g}", x)
            if hi is not None and x > hi:
                raise _SchemaError(path, f"{_show(x)} is above the accepted maximum {hi:g}", x)
    if isinstance(x, (list, tuple, np.ndarray)) and t == "array":
        n = len(x)
        lo, hi = node.get("minItems"), node.get("maxItems")
        if lo is not None and n < lo or hi is not None and n > hi:
            want = (f"{lo}" if lo == hi else f"at least {lo}" if hi is None else
                    f"at most {hi}" if lo is None else f"{lo} to {hi}")
            raise _SchemaError(path, f"expected {want} item{'s' if (hi or lo) != 1 else ''}, got {_show(x)}", x)
        pre = node.get("prefixItems", [])
        for i, v in enumerate(x):
            sub = pre[i] if i < len(pre) else node.get("items")
            if sub is not None:
                _check(v, sub, path + [i])
    if isinstance(x, Mapping) and t == "object":
        for req in node.get("required", ()):
            if req not in x:
                raise _SchemaError(path, f"missing required key {req!r}", x)
        props = node.get("properties", {})
        names = node.get("propertyNames")
        extra = node.get("additionalProperties", True)
        for key, v in x.items():
            if names is not None and not (isinstance(key, str) and re.fullmatch(_resolve(names)["pattern"], key)):
                raise _SchemaError(path + [key], f"key {key!r} is not a node index (a decimal integer)", key)
            if key in props:
                _check(v, props[key], path + [key])
            elif extra is False:
                raise _SchemaError(path + [key], f"unknown key {key!r}", key)
            elif isinstance(extra, dict):
                _check(v, extra, path + [key])


def validate_dict(d: Mapping[str, Any]) -> None:
    """Check a JSON-like mapping against the structure schema; raise :class:`StructureError`
    naming the key, the index and the value, and citing the schema's description of the key."""
    try:
        _check(d, schema(), [])
    except _SchemaError as e:
        key = e.path[0] if e.path else None
        desc = _describe(key) if isinstance(key, str) else ""
        msg = f"{_loc(e.path)}: {e.problem}"
        raise StructureError(msg + (f" (schema, {key}: {desc})" if desc else "")) from None


# ---------------------------------------------------------------------- values
def _numeric(value, key: str) -> np.ndarray:
    """``value`` as a float array; a :class:`StructureError` naming ``key``, the index and the
    value for booleans, strings, null, ragged lists and numbers too large for a double."""
    if isinstance(value, np.ndarray) and value.dtype.kind in "iuf":
        return np.array(value, dtype=float)

    def shape(x, path):
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating,
                                                                     list, tuple, np.ndarray)):
            raise StructureError(f"{_loc([key] + path)}: expected a number, got {_show(x)}")
        if isinstance(x, (list, tuple, np.ndarray)):
            if isinstance(x, np.ndarray) and x.dtype.kind in "iuf":
                return x.shape
            shapes = [shape(v, path + [i]) for i, v in enumerate(x)]
            for i, s in enumerate(shapes):
                if s != shapes[0]:
                    raise StructureError(
                        f"{_loc([key] + path + [i])}: ragged list: expected "
                        f"{'a number' if not shapes[0] else f'a list of {shapes[0][0]} items'} like item 0, "
                        f"got {_show(x[i])}")
            return (len(x),) + (shapes[0] if shapes else ())
        if isinstance(x, (int, np.integer)) and not isinstance(x, np.integer):
            try:
                float(x)
            except OverflowError:
                raise StructureError(f"{_loc([key] + path)}: {_show(x)} is too large for a double") from None
        return ()
    shape(value, [])
    return np.array(value, dtype=float)


def _in_range(arr: np.ndarray, key: str, kind: str, unit: str, item: str) -> None:
    """Raise if an entry of ``arr`` is outside the schema's ``$defs[kind]`` range."""
    spec = schema()["$defs"][kind]
    lo, hi = spec.get("minimum", -math.inf), spec.get("maximum", math.inf)
    bad = np.argwhere((arr < lo) | (arr > hi))
    if bad.size:
        idx = tuple(int(i) for i in bad[0])
        where = key + "".join(f"[{i}]" for i in idx) + (f" ({item} {idx[0]})" if idx else "")
        desc = _describe(key.split("[")[0])
        raise StructureError(f"{where}: {float(arr[idx]):.6g} {unit} is outside the accepted range "
                             f"[{lo:g}, {hi:g}] {unit}" + (f" (schema, {key.split('[')[0]}: {desc})" if desc else ""))


def _as_per_item(value: Any, count: int, field_name: str, item: str) -> np.ndarray:
    """Broadcast a number or per-item list to a float array of length ``count``."""
    arr = _numeric(value, field_name)
    if arr.ndim == 0:
        arr = np.full(count, float(arr))
    if arr.shape != (count,):
        raise StructureError(
            f"{field_name}: expected a number or a list of {count} values (one per {item}), "
            f"got shape {arr.shape}")
    return arr


# ---------------------------------------------------------------------- JSON text
def _strict_number(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"the number {text[:30]} is too large for a double")
    return v


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _no_duplicates(pairs):
    d = {}
    for k, v in pairs:
        if k in d:
            raise ValueError(f"duplicate key {k!r}")
        d[k] = v
    return d


def loads(text: str, source: str = "<string>") -> Any:
    """Strict JSON parsing: no NaN/Infinity, no number beyond a double's range, no duplicate
    keys; a :class:`StructureError` naming ``source`` and the line otherwise."""
    try:
        return json.loads(text, parse_float=_strict_number, parse_constant=_reject_constant,
                          object_pairs_hook=_no_duplicates)
    except json.JSONDecodeError as e:
        raise StructureError(f"{source}: not valid JSON ({e})") from None
    except ValueError as e:      # from the hooks above; also int() of more than 4300 digits
        raise StructureError(f"{source}: not valid JSON ({e})") from None
    except RecursionError:
        raise StructureError(f"{source}: not valid JSON (nested too deeply)") from None


