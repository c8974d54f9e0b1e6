#!/usr/bin/env bash
# Interleaved before/after micro-benchmarks: before = a609e04 (git worktree at $OLD), after = this
# checkout; two rounds each, alternating, one numba thread. Outputs: before_<bench>_<round>.txt, after_...
# The scripts: ../kernel_call_bench.py and ../one_driver_bench/batch_serial_bench.py (the earlier
# refactors' micro-benchmarks, reused) and env_step_bench.py here.
set -u
OLD=${OLD:-/tmp/old_a609}
NEW=${NEW:-$(cd "$(dirname "$0")/../../.." && pwd)}
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${OUT:-$HERE/../../../results/refactor/$(basename "$HERE")}   # raw outputs stay under results/
PY=${PY:-$NEW/.venv/bin/python}
export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
for round in 1 2; do
  for script in "$HERE/../kernel_call_bench.py" "$HERE/../one_driver_bench/batch_serial_bench.py" \
                "$HERE/env_step_bench.py"; do
    b=$(basename "$script" .py)
    PYTHONPATH=$OLD $PY "$script" > "$OUT/before_${b}_$round.txt" 2>/dev/null
    PYTHONPATH=$NEW $PY "$script" > "$OUT/after_${b}_$round.txt" 2>/dev/null
  done
done
