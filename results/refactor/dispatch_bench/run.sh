#!/usr/bin/env bash
# Interleaved before/after of session 21's dispatch change: before = c6d4685 (worktree $OLD),
# after = 3acede3 (worktree $NEW); two rounds each, alternating, one numba thread.
set -u
OLD=${OLD:-/tmp/w_before}
NEW=${NEW:-/tmp/w_after}
HERE=$(cd "$(dirname "$0")" && pwd)
PY=${PY:-python}
export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
for round in 1 2; do
  for script in "$HERE/dispatch_bench.py" "$HERE/../string_forces_bench/env_step_bench.py"; do
    b=$(basename "$script" .py)
    PYTHONPATH=$OLD $PY "$script" > "$HERE/before_${b}_$round.txt" 2>/dev/null
    PYTHONPATH=$NEW $PY "$script" > "$HERE/after_${b}_$round.txt" 2>/dev/null
  done
done
