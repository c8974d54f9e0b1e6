"""Parsing of command-line values and of rl-baselines3-zoo's string forms, without ``eval``.

* ``--env-kwargs`` / ``--hyperparams`` values (:func:`parse_kv_list`, :func:`parse_value`);
* zoo strings such as ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"`` with a restricted AST
  walker (:func:`safe_literal`);
* YAML files with errors that name the file and line (:func:`read_yaml`), and config values as
  plain YAML/JSON types (:func:`to_yaml_safe`);
* argparse ``type=`` functions from the package's checks (:func:`arg_type`).
"""
from __future__ import annotations

import argparse
import ast
import difflib
import json
from pathlib import Path
from typing import Any

import numpy as np

from tensegrity_gym.core.checks import read_bounded

#: largest YAML file (a configuration) read, bytes
MAX_YAML_BYTES = 16 * 2**20


def _torch_name(dotted: str):
    """Whitelisted names allowed in zoo strings: torch activation / optimizer classes."""
    import torch
    parts = dotted.split(".")
    if parts[0] in ("th", "torch"):
        parts = parts[1:]
    if len(parts) == 2 and parts[0] == "nn":
        obj = getattr(torch.nn, parts[1], None)
        if isinstance(obj, type) and issubclass(obj, torch.nn.Module):
            return obj
    if len(parts) == 2 and parts[0] == "optim":
        obj = getattr(torch.optim, parts[1], None)
        if isinstance(obj, type) and issubclass(obj, torch.optim.Optimizer):
            return obj
    raise ValueError(f"name {dotted!r} is not allowed here; only torch activation/optimizer classes "
                     "such as nn.Tanh, nn.ReLU, th.optim.Adam")


def safe_literal(text: str) -> Any:
    """Parse a Python-like literal that may use ``dict(...)`` calls and ``nn.<Activation>`` names.

    Accepts: numbers, strings, True/False/None, lists, tuples, dicts, ``dict(k=v, ...)``,
    unary minus, and whitelisted torch class names. Anything else (function calls, attribute
    access on other modules, comprehensions, ...) raises ValueError. Never calls ``eval``.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as e:
        raise ValueError(f"cannot parse {text!r}: {e.msg}") from None

    def conv(n):
        if isinstance(n, ast.Constant):
            return n.value
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, (ast.USub, ast.UAdd)):
            v = conv(n.operand)
            if not isinstance(v, (int, float)):
                raise ValueError(f"cannot negate {v!r} in {text!r}")
            return -v if isinstance(n.op, ast.USub) else v
        if isinstance(n, ast.List):
            return [conv(e) for e in n.elts]
        if isinstance(n, ast.Tuple):
            return tuple(conv(e) for e in n.elts)
        if isinstance(n, ast.Dict):
            return {conv(k): conv(v) for k, v in zip(n.keys, n.values)}
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "dict" and not n.args:
            return {kw.arg: conv(kw.value) for kw in n.keywords}
        if isinstance(n, ast.Name) and n.id in ("True", "False", "None"):
            return {"True": True, "False": False, "None": None}[n.id]
        if isinstance(n, (ast.Name, ast.Attribute)):
            return _torch_name(ast.unparse(n))
        raise ValueError(f"unsupported expression {ast.unparse(n)!r} in {text!r} (only literals, dict(...) "
                         "and torch class names are accepted)")

    return conv(tree)


def parse_value(text: str) -> Any:
    """Value of a command-line ``key:value`` / ``key=value``: JSON, else a Python literal, else the string."""
    s = text.strip()
    for lit in ({"true": True, "false": False, "null": None, "none": None},):
        if s.lower() in lit:
            return lit[s.lower()]
    try:
        return json.loads(s)
    except (json.JSONDecodeError, ValueError):
        pass
    try:
        return ast.literal_eval(s)
    except (ValueError, SyntaxError):
        return s


def parse_kv_list(items: list[str] | None, sep: str, what: str) -> dict:
    """``["a:1", "b:rest_length"]`` -> ``{"a": 1, "b": "rest_length"}``; a single JSON object is accepted too."""
    out: dict = {}
    if not items:
        return out
    if len(items) == 1 and items[0].strip().startswith("{"):
        try:
            d = json.loads(items[0])
        except json.JSONDecodeError as e:
            raise ValueError(f"{what}: invalid JSON object {items[0]!r}: {e}") from None
        if not isinstance(d, dict):
            raise ValueError(f"{what}: expected a JSON object, got {items[0]!r}")
        return d
    for item in items:
        if sep not in item:
            raise ValueError(f"{what}: expected key{sep}value, got {item!r}")
        k, v = item.split(sep, 1)
        k = k.strip()
        if not k:
            raise ValueError(f"{what}: empty key in {item!r}")
        out[k] = parse_value(v)
    return out



def read_yaml(path: str | Path):
    """The YAML document in ``path``; ValueError naming the file, the line and the problem for a
    file that is not valid YAML or not UTF-8 text (PyYAML's parser traceback otherwise)."""
    import yaml
    path = Path(path)
    try:
        text = read_bounded(path, MAX_YAML_BYTES, "YAML file", binary=True)    # FIFOs and devices refused
        return yaml.safe_load(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text (UTF-8) file") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ValueError(f"{path}: not valid YAML{where}: {problem}") from None



def arg_type(check, kind=float):
    """An argparse ``type=`` from a check of this package (``check(value)`` -> value or
    ValueError): the text is parsed by ``kind``, then checked; errors become argparse's one-line
    usage errors (exit code 2)."""
    def parse(text):
        try:
            v = kind(text)
        except (TypeError, ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        try:
            return check(v)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e).split(": ", 1)[-1]) from None
    return parse


def to_yaml_safe(obj):
    """Config values as plain YAML/JSON types (classes by name, schedules as lin_x)."""
    if isinstance(obj, dict):
        return {str(k): to_yaml_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_yaml_safe(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, type):
        return f"{obj.__module__}.{obj.__qualname__}"
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return repr(obj)



def did_you_mean(key: str, names) -> str:
    """`` (did you mean a, b?)`` for the accepted names nearest ``key``, or ``""``."""
    close = difflib.get_close_matches(key, names, n=3)
    return f" (did you mean {', '.join(close)}?)" if close else ""


def shipped_files(folder: Path) -> list[str]:
    """The names of the ``.yml`` files shipped under ``folder``, relative to it (``ppo.yml``,
    ``time_to_policy/ppo.yml``)."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.yml"))


def find_file(name: str | Path, folder: Path, label: str) -> Path:
    """The file a command-line argument names: the user's own if ``name`` is one (absolute, or
    relative to the working directory), else the shipped file of that name relative to
    ``folder``. FileNotFoundError naming ``label``, both places looked at and the shipped names."""
    path = Path(name)
    if path.is_file():
        return path
    shipped = folder / path
    if not path.is_absolute() and shipped.is_file():
        return shipped
    raise FileNotFoundError(f"{label} {name} does not exist (looked for {path.absolute()} and {shipped}); "
                            f"the shipped files: {', '.join(shipped_files(folder))}")
