#!/usr/bin/env bash
# Run many short agents.train runs in parallel, one core each, then summarise them.
#
#   bash scripts/sweep_train.sh agents/sweeps/sweep1.txt runs_sweep 450 > results/sweeps/sweep1.json
#
# Each line of the runs file is "NAME ARGS..." (ARGS go to `python -m agents.train`). Every run gets
# --log-dir RUNS_DIR/NAME --max-wall-time WALL --save-freq -1 and one core (torch and numba threads 1).
# The summary (stdout, JSON) holds each run's state.json and its evaluation curve (return and
# success rate vs env steps). Launch no more runs than the machine has cores.
# The committed sweeps (results/sweeps/sweep*.json) ran this on a 16-core machine with WALL = 450,
# 420 and 330 s.
set -euo pipefail
RUNS_FILE=${1:?runs file}; RUNS_DIR=${2:-runs_sweep}; WALL=${3:-450}
export PYTHONUNBUFFERED=1 NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 MPLBACKEND=Agg
PY=${PYTHON:-python}
mkdir -p "$RUNS_DIR"
# compile the numba kernels once (cached) so the parallel runs do not all compile them
$PY -c "import gymnasium as gym, tensegrity_gym
for i, kw in (('TensegrityShape-v0', {}), ('TensegrityShape-v0', {'action_mode': 'force_density'}), ('TensegrityRoll-v0', {})):
    e = gym.make(i, **kw); e.reset(seed=0); e.step(e.action_space.sample()); e.close()" >&2
while read -r name rest; do
  [ -z "$name" ] && continue
  # the args may hold quoted values (policy_kwargs with spaces): let the shell split them
  eval "set -- $rest"
  ( $PY -m agents.train --log-dir "$RUNS_DIR/$name" --no-progress-bar --max-wall-time "$WALL" --save-freq -1 "$@" \
      > "$RUNS_DIR/$name.log" 2>&1; echo "$name rc=$?" >&2 ) &
done < "$RUNS_FILE"
wait
$PY - "$RUNS_DIR" <<'PYEOF'
import json, pathlib, sys
import numpy as np
out = {}
for d in sorted(p for p in pathlib.Path(sys.argv[1]).iterdir() if p.is_dir()):
    r = {}
    if (d / "state.json").exists():
        r["state"] = json.loads((d / "state.json").read_text())
    ev = d / "eval" / "evaluations.npz"
    if ev.exists():
        z = np.load(ev)
        r["eval_steps"] = z["timesteps"].tolist()
        r["eval_return"] = z["results"].mean(axis=1).round(3).tolist()
        if "successes" in z and z["successes"].size:
            r["eval_success"] = z["successes"].mean(axis=1).round(3).tolist()
    out[d.name] = r
print(json.dumps(out, indent=1))
PYEOF
