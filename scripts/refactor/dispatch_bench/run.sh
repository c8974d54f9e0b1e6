#!/usr/bin/env bash
# Interleaved before/after of the dispatch change: before = c6d4685 (worktree $OLD),
# after = 3acede3 (worktree $NEW); two rounds each, alternating, one numba thread.
set -u
OLD=${OLD:-/tmp/w_before}
NEW=${NEW:-/tmp/w_after}
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${OUT:-$HERE/../../../results/refactor/$(basename "$HERE")}   # raw outputs stay under results/
PY=${PY:-python}
export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
for round in 1 2; do
  for script in "$HERE/dispatch_bench.py" "$HERE/../string_forces_bench/env_step_bench.py"; do
    b=$(basename "$script" .py)
    PYTHONPATH=$OLD $PY "$script" > "$OUT/before_${b}_$round.txt" 2>/dev/null
    PYTHONPATH=$NEW $PY "$script" > "$OUT/after_${b}_$round.txt" 2>/dev/null
  done
done
