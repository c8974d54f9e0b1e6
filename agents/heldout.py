"""Held-out reset seeds: an evaluation's reset seeds must be disjoint from every reset seed the
evaluated training runs used, for training or for their own evaluation and model selection.

The rule, from what :mod:`agents.train` does (:mod:`agents.trainer`, :func:`agents.envs.make_vec`),
for a run folder whose ``config.yaml`` records ``seed`` s, ``n_envs`` n, ``eval_freq`` f,
``n_eval_envs`` m and ``eval_seed`` e:

* training env i (0 <= i < n) is reset first from seed s + i;
* with f > 0, the evaluation env used during training (its ``EvalCallback``: the learning curve in
  ``eval/evaluations.npz`` and the choice of ``best_model.zip``) is reset first from seed e + i
  (0 <= i < m), e = s + :data:`agents.trainer.EVAL_SEED_OFFSET` (10 000);
* every later episode of those envs (an automatic reset, the next evaluation, a resumed segment's
  envs seeded again the same way) draws from the same env's generator without a new seed, so it
  is not the episode of any fresh reset seed;
* a run started with ``--warm-start`` from another run (``warm_start.run`` in ``config.yaml``) also
  counts that run's seeds, found the same way in its own ``config.yaml`` (the path as recorded,
  relative to the working directory or to the repository root); a source whose folder is gone
  cannot be read and is named in a note.

So a run used the reset seeds ``[s, s + n)`` and, when it evaluated during training,
``[e, e + m)``; an older ``config.yaml`` without ``eval_freq`` / ``n_eval_envs`` / ``eval_seed``
counts the widest the trainer's defaults allow (evaluated, m = 10, e = s + 10 000). A held-out
evaluation on the reset seeds ``[first, first + N)`` must share none of them with any evaluated
run: :func:`check_heldout` raises ValueError naming the run and the overlapping seeds (the scripts
exit with status 2, as for any bad argument), and there is no option to evaluate anyway. Choose
another ``--seed``. What a run folder cannot record, e.g. a training length chosen after looking at
a held-out result, is not caught here: such a choice needs fresh seeds too.
"""
from __future__ import annotations

import sys
from pathlib import Path

from .common import REPO_ROOT, read_run_config
from .envs import check_seed

#: the evaluation env's seeds during training start at ``seed + EVAL_SEED_OFFSET`` (agents.trainer
#: seeds its evaluation env with it)
EVAL_SEED_OFFSET = 10_000
#: the most evaluation envs the trainer's default gives (``min(eval episodes, 10)``)
DEFAULT_MAX_EVAL_ENVS = 10


def find_run_dir(path: str | Path) -> Path | None:
    """The run folder of ``path``: itself if it holds ``config.yaml``; for a model file (a
    ``.zip`` in the run folder or in its ``checkpoints/``) the nearest folder above it that holds
    one (two levels at most); None if there is none."""
    p = Path(path)
    if p.is_dir():
        return p if (p / "config.yaml").is_file() else None
    for parent in list(p.parents)[:2]:
        if (parent / "config.yaml").is_file():
            return parent
    return None


def _resolve(recorded: str) -> Path | None:
    """A run folder recorded in a ``config.yaml`` (as given on agents.train's command line): as
    is, then relative to the repository root; None if neither holds a ``config.yaml``."""
    for p in (Path(recorded), REPO_ROOT / recorded):
        if (p / "config.yaml").is_file():
            return p
    return None


def run_reset_seeds(run_dir: str | Path, _seen: frozenset = frozenset()) -> list[tuple[str, int, int, str]]:
    """The reset seeds the run in ``run_dir`` used (the module's rule): a list of ``(run, first,
    stop, what)``, seeds ``first <= s < stop``, ``what`` saying which env drew them, including
    those of a warm-start source run. ValueError (naming the file) for a ``config.yaml`` that is
    not agents.train's."""
    run_dir = Path(run_dir)
    cfg = read_run_config(run_dir / "config.yaml")
    try:
        s, n = int(cfg["seed"]), int(cfg["n_envs"])
        eval_freq = cfg.get("eval_freq", 1)
        evaluated = eval_freq is None or int(eval_freq) > 0
        m = int(cfg.get("n_eval_envs") or DEFAULT_MAX_EVAL_ENVS)
        e = int(cfg.get("eval_seed", s + EVAL_SEED_OFFSET))
    except (TypeError, ValueError):
        raise ValueError(f"{run_dir / 'config.yaml'}: seed, n_envs, eval_freq, n_eval_envs and eval_seed must be "
                         "integers (the config.yaml agents.train writes)") from None
    out = [(str(run_dir), s, s + n, "its training envs")]
    if evaluated:
        out.append((str(run_dir), e, e + m, "its evaluation env during training"))
    source = (cfg.get("warm_start") or {}).get("run") if isinstance(cfg.get("warm_start"), dict) else None
    if source:
        src = _resolve(str(source))
        if src is None:
            print(f"note: {run_dir}: its warm-start source {source} is not here; its seeds are not checked",
                  file=sys.stderr)
        elif src.resolve() not in _seen:
            out += [(f"{r} (the warm start of {run_dir})", a, b, w)
                    for r, a, b, w in run_reset_seeds(src, _seen | {run_dir.resolve()})]
    return out


def _ranges(values: list[int]) -> str:
    """``values`` (sorted ints) as ``a..b`` ranges: ``10000..10007, 10020``."""
    parts, i = [], 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        parts.append(str(values[i]) if i == j else f"{values[i]}..{values[j]}")
        i = j + 1
    return ", ".join(parts)


def heldout_seeds(first: int, count: int, flag: str = "--seed") -> range:
    """The reset seeds ``first .. first + count - 1``; ValueError naming ``flag`` unless they all
    are valid seeds (integers in 0 .. 2**32 - 1)."""
    check_seed(first, flag)
    if count >= 1:
        check_seed(first + count - 1, f"{flag} + episodes - 1")
    return range(int(first), int(first) + max(int(count), 0))


def check_heldout(seeds, runs, flag: str = "--seed") -> None:
    """ValueError naming the first run in ``runs`` (run folders or model files of agents.train;
    others, e.g. a baseline's name, are skipped) whose training or evaluation reset seeds (the
    module's rule) overlap the held-out reset seeds ``seeds``, and the overlapping seeds. A model
    file outside any run folder cannot be checked: a note on stderr says so."""
    seeds = sorted({int(x) for x in seeds})
    if not seeds:
        return
    lo, hi = seeds[0], seeds[-1]
    held = set(seeds)
    for run in runs:
        p = Path(run)
        if not p.exists():
            continue                      # not a path (a baseline's name): the caller's to judge
        run_dir = find_run_dir(p)
        if run_dir is None:
            print(f"note: {run}: no config.yaml in or above it; its training seeds are not checked", file=sys.stderr)
            continue
        for name, a, b, what in run_reset_seeds(run_dir):
            both = sorted(held.intersection(range(a, b)))
            if both:
                raise ValueError(f"{flag}: the held-out reset seeds {lo}..{hi} overlap those run {name} used "
                                 f"({what}: {a}..{b - 1}): {_ranges(both)}; choose a --seed clear of them")


def script_heldout_seeds(first: int, count: int, runs, flag: str = "--seed") -> range:
    """:func:`heldout_seeds` checked by :func:`check_heldout` against ``runs``, for a script: a
    refusal is the one-line ``error: ...`` on stderr and exit status 2 (SystemExit)."""
    try:
        seeds = heldout_seeds(first, count, flag)
        check_heldout(seeds, runs, flag)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    return seeds
