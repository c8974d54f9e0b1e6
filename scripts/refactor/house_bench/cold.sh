#!/usr/bin/env bash
# Cold compile before/after: gym.make + reset + first step in a process with an empty numba cache.
set -u
OLD=${OLD:?}; NEW=${NEW:?}; PY=${PY:-python}; HERE=$(cd "$(dirname "$0")" && pwd)
for side in base integ; do
  if [ $side = base ]; then W=$OLD; else W=$NEW; fi
  for id in TensegrityShape-v0 TensegrityRoll-v0; do
    d=$(mktemp -d); echo -n "$side: "
    NUMBA_CACHE_DIR=$d TENSEGRITY_GYM_QUIET=1 PYTHONPATH=$W $PY "$HERE/cold.py" $id 2>/dev/null
    rm -rf "$d"
  done
done
