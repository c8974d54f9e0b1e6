"""Helpers shared by the scripts that tabulate trained policies over held-out episodes, one run
folder per training seed (``scripts/eval/eval_climb.py``, ``eval_rough.py``, ``eval_navigate.py``, which
import it as ``scripts.eval._policy_table``). Not part of the installed package.

* :func:`table_parser` / :func:`parse_table_args` -- the arguments they share (run folders,
  ``--out``, ``--model``, ``--env-kwargs``, ``--no-baseline``);
* :func:`trained_policies` -- each run's policy and the model file it was loaded from;
* :func:`iqm_row` -- the IQM over training seeds with its 95 % bootstrap interval, min and max.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tensegrity_gym_agents.evaluate import load_trained
from tensegrity_gym_agents.summary import iqm_interval


def table_parser(doc: str, env_kwargs_help: str = "JSON object of extra env arguments") -> argparse.ArgumentParser:
    """A parser with the shared arguments (described by the first paragraph of ``doc``); the
    caller adds its own before :func:`parse_table_args`."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run folders of agents.train (one per training seed)")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--model", default="final", help="best, final or a model .zip")
    ap.add_argument("--env-kwargs", default="{}", help=env_kwargs_help)
    ap.add_argument("--no-baseline", action="store_true", help="skip the rolling gait")
    return ap


def parse_table_args(ap: argparse.ArgumentParser, argv=None) -> tuple[argparse.Namespace, dict]:
    """(arguments, env arguments from ``--env-kwargs``); the output folder is made."""
    args = ap.parse_args(argv)
    env_kwargs = json.loads(args.env_kwargs)
    args.out.mkdir(parents=True, exist_ok=True)
    return args, env_kwargs


def trained_policies(runs, which: str):
    """(run folder, policy, model file) of each run in ``runs``, loaded in turn (``which``: best,
    final or a model .zip)."""
    for run in runs:
        _, policy, model_path, _ = load_trained(run, which)
        yield run, policy, model_path


def iqm_row(vals) -> dict:
    """``iqm_m_s``, ``ci95_m_s`` ([low, high]), ``min_m_s``, ``max_m_s`` of speeds (m/s) over seeds."""
    iqm, lo, hi = iqm_interval(vals)
    return {"iqm_m_s": iqm, "ci95_m_s": [lo, hi], "min_m_s": float(min(vals)), "max_m_s": float(max(vals))}
