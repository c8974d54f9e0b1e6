#!/usr/bin/env bash
# Interleaved before/after benchmarks of the contact sub-steps moved into the loop driver:
# before = cbc9b27 (git worktree at $OLD), after = this checkout; two rounds each, alternating.
# ../contact_loop_bench.py: roll vector env, wall clock per vector step (20 contact sub-steps),
# numba's default threads (2 here), as results/refactor/contact_loop.md measured it;
# ../kernel_call_bench.py: B = 1 integrator calls without contact (the driver's other instances,
# whose source gained the pruned contact argument), one thread. Outputs: before_<bench>_<round>.txt, after_...
set -u
OLD=${OLD:-/tmp/before}
NEW=${NEW:-$(cd "$(dirname "$0")/../../.." && pwd)}
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${OUT:-$HERE/../../../results/refactor/$(basename "$HERE")}   # raw outputs stay under results/
PY=${PY:-$NEW/.venv/bin/python}
export OMP_NUM_THREADS=1
for round in 1 2; do
  for script in "$HERE/../contact_loop_bench.py" "$HERE/../kernel_call_bench.py"; do
    b=$(basename "$script" .py)
    if [ "$b" = kernel_call_bench ]; then export NUMBA_NUM_THREADS=1; else unset NUMBA_NUM_THREADS; fi
    PYTHONPATH=$OLD $PY "$script" > "$OUT/before_${b}_$round.txt" 2>/dev/null
    PYTHONPATH=$NEW $PY "$script" > "$OUT/after_${b}_$round.txt" 2>/dev/null
  done
done
# the project's env benchmark, roll env, the batched vector env and SyncVectorEnv (2 threads)
unset NUMBA_NUM_THREADS
for side in before after; do
  if [ $side = before ]; then P=$OLD; else P=$NEW; fi
  PYTHONPATH=$P $PY "$NEW/scripts/bench_envs.py" --env roll --methods batched sync --n-envs 1 16 256 4096 \
    --seconds 2 --out "$OUT/${side}_bench_envs" > "$OUT/${side}_bench_envs.txt" 2>/dev/null
done
