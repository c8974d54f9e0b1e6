#!/bin/bash
# Checks on the lent GPU machine, run from the repository root: device_checks.sh PART...
# (wheels of the packages the image lacks in .whl/: gymnasium, farama-notifications,
# stable-baselines3, rsl-rl-lib, tensordict and their needs). PARTs, each under its own time limit:
#   ttp_a, ttp_b, ttp_a1: time to policy, rsl_rl PPO on the compiled torch device env, env and
#       learner on the GPU (a: 8192 envs x 16 steps, 4 epochs x 4 minibatches; a1: the same, seed 1;
#       b: 4096 envs x 32 steps, 2 epochs x 8 minibatches);
#   ttp_c: 1024 envs x 32 steps, 2 epochs x 8 minibatches, entropy bonus 0.005 (the setting that left
#       the 0.03 m/s plateau in every CPU run, results/device_time_to_policy/README.md);
#   profile: where a control step of the torch env goes (scripts/bench/profile_torch_env.py);
#   pytest: the CUDA tests (torch backend, envs, device resets, terrain);
#   terrain: the torch terrain envs' throughput against flat ground, eager and compiled (float32);
#   With cuda_graph=True (each control step's physics replayed as one CUDA graph):
#   gprofile: a control step compiled against compiled + graphed (1024 and 8192 envs);
#   ttp_g: time to policy, 4096 envs x 32 steps, 2 epochs x 8 minibatches, entropy bonus 0.005, graphed;
#   ttp_g1, ttp_g8: the same with 1024 and 8192 envs;
#   gpytest: the graph tests (tests/test_torch_graphs.py) on CUDA;
#   gterrain: the terrain envs' throughput against flat ground, compiled and graphed (float32).
# Everything lands in $OUT (set by the device tool; defaults to ./runs/device here); each part
# prints its rows as it goes. On an H200, `gprofile ttp_g gpytest gterrain` took 467 s
# in one call, and gterrain's 150 s ended while steps compiled: next, `PYTEST_K="-k cuda" gpytest
# ttp_g8 gterrain` with TERRAIN_TIMEOUT=300 (gpytest -k cuda about 60 s, ttp_g8 about 130 s).
set -u
OUT=${OUT:-runs/device}; mkdir -p "$OUT"
PY=${PY:-python3}; DEV=${DEV:-cuda}; BUDGET=${BUDGET:-70}; SCALE=${SCALE:-1}
export PYTHONUNBUFFERED=1 TENSEGRITY_GYM_QUIET=1
if [ -d .whl ]; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target .site .whl/*.whl || exit 1
  mkdir -p .pp && ln -sfn "$PWD/agents" .pp/tensegrity_gym_agents
  export PYTHONPATH=$PWD/.site:$PWD:$PWD/.pp
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv > "$OUT/versions.txt" 2>&1
$PY -c "import torch, numba, numpy, gymnasium, rsl_rl, tensordict, tensegrity_gym, tensegrity_gym_agents.common as c; \
print('torch', torch.__version__, 'numba', numba.__version__, 'numpy', numpy.__version__, 'gymnasium', \
gymnasium.__version__, 'tensordict', tensordict.__version__, 'cpu', c.cpu_model(), 'cpus', c.cpus_available())" \
  >> "$OUT/versions.txt" 2>&1 || { cat "$OUT/versions.txt"; exit 1; }
cat "$OUT/versions.txt"
T="$PY -m scripts.eval.device_time_to_policy --device $DEV --compile --reset-sampling device --budget-s $BUDGET \
   --eval-every-s 10 --eval-envs 64 --label lent_device_machine"
ttp() {  # name envs steps epochs minibatches seed [more arguments]
  name=$1 envs=$2 steps=$3 epochs=$4 mb=$5 seed=$6; shift 6
  timeout ${TTP_TIMEOUT:-160} $T --num-envs $((envs / SCALE)) --steps-per-env $steps --epochs $epochs --mini-batches $mb \
    --seed $seed --out "$OUT/ttp_$name.json" "$@" > "$OUT/ttp_$name.log" 2>&1
  grep -E "training,|reach" "$OUT/ttp_$name.log" | tail -n 12
}
for part in "$@"; do
  echo "== $part"
  case $part in
    ttp_a) ttp 8192x16_s0 8192 16 4 4 0 ;;
    ttp_a1) ttp 8192x16_s1 8192 16 4 4 1 ;;
    ttp_b) ttp 4096x32_s0 4096 32 2 8 0 ;;
    ttp_c) ttp 1024x32_ent005_s0 1024 32 2 8 0 --entropy-coef 0.005 ;;
    ttp_g) ttp 4096x32_ent005_graph_s0 4096 32 2 8 0 --entropy-coef 0.005 --cuda-graph ;;
    ttp_g1) ttp 1024x32_ent005_graph_s0 1024 32 2 8 0 --entropy-coef 0.005 --cuda-graph ;;
    ttp_g8) ttp 8192x32_ent005_graph_s0 8192 32 2 8 0 --entropy-coef 0.005 --cuda-graph ;;
    gprofile) timeout 120 $PY -m scripts.bench.profile_torch_env --device $DEV --num-envs $((1024 / SCALE)) $((8192 / SCALE)) \
                --compile --cuda-graph --no-eager --json "$OUT/profile_graph.json" > "$OUT/profile_graph.log" 2>&1
              tail -n 6 "$OUT/profile_graph.log" ;;
    gpytest) timeout ${PYTEST_TIMEOUT:-100} $PY -m pytest -q -p no:cacheprovider tests/test_torch_graphs.py ${PYTEST_K:-} > "$OUT/pytest_graph.log" 2>&1
             tail -n 3 "$OUT/pytest_graph.log" ;;
    gterrain) timeout ${TERRAIN_TIMEOUT:-150} $PY -m scripts.bench.bench_terrain --batch --torch-envs $((16384 / SCALE)) --torch-env-steps 10 \
                --torch-no-eager --torch-compile --torch-cuda-graph --torch-device $DEV --torch-dtype float32 \
                --torch-scenes flat "slope 20 deg" "rough 2 cm (heightfield)" "steps (4 boxes)" \
                --json "$OUT/bench_terrain_graph.json" > "$OUT/bench_terrain_graph.log" 2>&1
              tail -n 12 "$OUT/bench_terrain_graph.log" ;;
    profile) timeout 200 $PY -m scripts.bench.profile_torch_env --device $DEV --num-envs 64 $((8192 / SCALE)) --compile \
               --json "$OUT/profile_torch_env.json" > "$OUT/profile.log" 2>&1; tail -n 6 "$OUT/profile.log" ;;
    pytest) timeout 170 $PY -m pytest -q -p no:cacheprovider tests/test_torch_backend.py tests/test_torch_env.py \
              tests/test_torch_reset.py tests/test_torch_terrain.py -k cuda > "$OUT/pytest_cuda.log" 2>&1
            tail -n 3 "$OUT/pytest_cuda.log" ;;
    terrain) timeout 240 $PY -m scripts.bench.bench_terrain --batch --torch-envs $((16384 / SCALE)) --torch-env-steps 10 \
               --torch-compile --torch-device $DEV --torch-dtype float32 --torch-scenes flat "slope 20 deg" \
               "rough 2 cm (heightfield)" "steps (4 boxes)" --json "$OUT/bench_terrain_torch_env.json" \
               > "$OUT/bench_terrain.log" 2>&1
             tail -n 12 "$OUT/bench_terrain.log" ;;
    *) echo "unknown part $part"; exit 2 ;;
  esac
done
