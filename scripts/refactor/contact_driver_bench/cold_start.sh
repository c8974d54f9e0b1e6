#!/usr/bin/env bash
# Cold start of the roll env (no numba cache: a fresh clone), before (cbc9b27) and after (HEAD of
# the checkout this script is in): seconds for import + gym.make + reset, the first env.step(),
# then make_vec(num_envs=64) + reset and its first step (the SIMD contact instance).
# Output: cold_start.txt.
set -u
NEW=$(cd "$(dirname "$0")/../../.." && pwd)
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${OUT:-$HERE/../../../results/refactor/$(basename "$HERE")}   # raw outputs stay under results/
PY=${PY:-$NEW/.venv/bin/python}
: > "$OUT/cold_start.txt"
for side in before after; do
  D=/tmp/cold_$side
  rm -rf "$D"; git clone -q "$NEW" "$D"
  if [ $side = before ]; then git -C "$D" checkout -q cbc9b27; fi
  echo "$side $(git -C "$D" rev-parse --short HEAD)" >> "$OUT/cold_start.txt"
  (cd /tmp && PYTHONPATH=$D $PY -c "
import time
t0 = time.perf_counter()
import gymnasium as gym, tensegrity_gym
e = gym.make('TensegrityRoll-v0'); e.reset(seed=0)
t1 = time.perf_counter(); e.step(e.action_space.sample()); t2 = time.perf_counter()
v = gym.make_vec('TensegrityRoll-v0', num_envs=64, vectorization_mode='vector_entry_point'); v.reset(seed=0)
t3 = time.perf_counter(); v.step(v.action_space.sample()); t4 = time.perf_counter()
print(f'  make+reset {t1 - t0:.1f} s, first step {t2 - t1:.1f} s; vector 64 make+reset {t3 - t2:.1f} s, first step {t4 - t3:.1f} s; total {t4 - t0:.1f} s')
" 2>/dev/null) >> "$OUT/cold_start.txt"
done
cat "$OUT/cold_start.txt"
