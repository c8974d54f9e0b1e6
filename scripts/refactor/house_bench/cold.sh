#!/usr/bin/env bash
# Cold compile before/after: scripts/bench_compile.py (gym.make + reset + first step in a process
# with an empty numba cache) run on each checkout's own package.
set -u
OLD=${OLD:?}; NEW=${NEW:?}; PY=${PY:-python}; HERE=$(cd "$(dirname "$0")" && pwd)
for W in "$OLD" "$NEW"; do
  PYTHONPATH=$W $PY "$HERE/../../bench_compile.py"
done
