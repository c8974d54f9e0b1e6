#!/usr/bin/env bash
# Before/after of the layered package, interleaved: OLD and NEW are worktrees of the two commits;
# each runs its own copy of each script on its own package, two rounds, alternating.
# Outputs in results/refactor/house_bench/; then: python table.py > ../../../results/refactor/house_bench/table.md
set -u
OLD=${OLD:?worktree of the commit before}; NEW=${NEW:?worktree of the commit after}
PY=${PY:-python}
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${OUT:-$HERE/../../../results/refactor/house_bench}; mkdir -p "$OUT"
for round in 1 2; do
  for side in base integ; do
    if [ $side = base ]; then cd "$OLD"; else cd "$NEW"; fi
    PYTHONPATH=$PWD $PY scripts/bench_dynamics.py --quick --no-mujoco > "$OUT/${side}_dyn_$round.txt" 2>&1
    PYTHONPATH=$PWD NUMBA_NUM_THREADS=1 $PY scripts/bench_step_overhead.py --rounds 20 --repeats 3 > "$OUT/${side}_overhead_$round.txt" 2>&1
    PYTHONPATH=$PWD $PY scripts/bench_envs.py --env all --methods batched --n-envs 1 16 256 --seconds 1 --out "$OUT/${side}_envs_$round" > "$OUT/${side}_envs_$round.txt" 2>&1
    PYTHONPATH=$PWD $PY scripts/bench_gpu.py --quick --threads 1 --out "$OUT/${side}_gpu_$round.json" > "$OUT/${side}_gpu_$round.txt" 2>&1
    PYTHONPATH=$PWD NUMBA_NUM_THREADS=2 $PY "$HERE/kern.py" > "$OUT/${side}_kern_$round.txt" 2>&1
  done
done
