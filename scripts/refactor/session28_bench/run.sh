#!/usr/bin/env bash
# before/after speed, interleaved: OLD and NEW are checkouts of the two commits (each with a warm numba cache)
set -u
OLD=${OLD:?checkout before}; NEW=${NEW:?checkout after}
export TENSEGRITY_GYM_QUIET=1
OUT=${OUT:-$(cd "$(dirname "$0")/../../../results/refactor/session28" && pwd)}
KERN=$NEW/scripts/refactor/house_bench/kern.py
for round in 3 4; do
  for side in base main; do
    if [ $side = base ]; then W=$OLD; else W=$NEW; fi
    cd $W
    PYTHONPATH=$W NUMBA_NUM_THREADS=2 python $KERN > $OUT/${side}_kern_$round.txt 2>&1
    PYTHONPATH=$W python scripts/bench_envs.py --env all --methods batched --n-envs 1 16 256 --seconds 1 --out $OUT/${side}_envs_$round > $OUT/${side}_envs_$round.txt 2>&1
    PYTHONPATH=$W NUMBA_NUM_THREADS=1 python scripts/bench_step_overhead.py --rounds 10 --repeats 2 > $OUT/${side}_overhead_$round.txt 2>&1
  done
done
echo done
