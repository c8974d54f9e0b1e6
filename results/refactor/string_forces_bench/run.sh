#!/usr/bin/env bash
# Interleaved before/after micro-benchmarks: before = a609e04 (git worktree at $OLD), after = this
# checkout; two rounds each, alternating, one numba thread. Outputs: before_<bench>_<round>.txt, after_...
set -u
OLD=${OLD:-/tmp/old_a609}
NEW=${NEW:-$(cd "$(dirname "$0")/../../.." && pwd)}
HERE=$(cd "$(dirname "$0")" && pwd)
PY=${PY:-$NEW/.venv/bin/python}
export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
for round in 1 2; do
  for b in kernel_call_bench batch_serial_bench env_step_bench; do
    PYTHONPATH=$OLD $PY "$HERE/$b.py" > "$HERE/before_${b}_$round.txt" 2>/dev/null
    PYTHONPATH=$NEW $PY "$HERE/$b.py" > "$HERE/after_${b}_$round.txt" 2>/dev/null
  done
done
