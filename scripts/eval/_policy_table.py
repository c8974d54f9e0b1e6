"""Helpers shared by the scripts that tabulate trained policies over held-out episodes, one run
folder per training seed (``scripts/eval/eval_climb.py``, ``eval_rough.py``, ``eval_navigate.py``, which
import it as ``scripts.eval._policy_table``). Not part of the installed package.

* :func:`table_parser` / :func:`parse_table_args` -- the arguments they share (run folders,
  ``--out``, ``--model``, ``--env-kwargs``, ``--no-baseline``, ``--seed``);
* :func:`held_out` -- the held-out reset seeds, refused (exit status 2) where a run trained or
  evaluated on one of them (:mod:`agents.heldout`);
* :func:`trained_policies` -- each run's policy and the model file it was loaded from;
* :func:`iqm_row` -- the IQM over training seeds with its 95 % bootstrap interval, min and max;
* :func:`seed_row` -- one training seed's mean over its episodes with its 95 % bootstrap interval.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tensegrity_gym_agents.evaluate import load_trained
from tensegrity_gym_agents.heldout import script_heldout_seeds
from tensegrity_gym_agents.summary import iqm_interval, mean_interval


def table_parser(doc: str, seed0: int, env_kwargs_help: str = "JSON object of extra env arguments") -> argparse.ArgumentParser:
    """A parser with the shared arguments (described by the first paragraph of ``doc``;
    ``--seed`` defaults to ``seed0``); the caller adds its own before :func:`parse_table_args`."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=seed0,
                    help=f"first held-out reset seed (default {seed0}); must be clear of every run's own seeds")
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


def held_out(args: argparse.Namespace, count: int) -> list[int]:
    """The held-out reset seeds ``--seed`` .. ``--seed + count - 1``, checked against every run
    folder in ``args.runs`` (:func:`agents.heldout.check_heldout`): an overlap ends the script
    with a one-line error and exit status 2."""
    return list(script_heldout_seeds(args.seed, count, args.runs))


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


def seed_row(x) -> dict:
    """``mean`` and ``ci95`` ([low, high], percentile bootstrap over the episodes,
    :func:`agents.summary.mean_interval`) of one training seed's per-episode values ``x``."""
    mean, lo, hi = mean_interval(x)
    return {"mean": mean, "ci95": [lo, hi]}
