#!/bin/bash
# four trainings at once on the lent 16-core H100 machine; each stops itself after WALL s
set -u
WALL=${WALL:-390}
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=2 MKL_NUM_THREADS=2
mkdir -p runs_gpu
T="python3 -m agents.train --no-progress-bar --max-wall-time $WALL"
NUMBA_NUM_THREADS=3 $T --algo ppo --env TensegrityShape-v0 --seed 0 --device cuda --num-threads 2 \
  --log-dir runs_gpu/ppo_shape_policy_cuda > runs_gpu/a.log 2>&1 &
NUMBA_NUM_THREADS=3 $T --algo ppo --env TensegrityShape-v0 --seed 0 --device cpu --num-threads 3 \
  --log-dir runs_gpu/ppo_shape_policy_cpu > runs_gpu/b.log 2>&1 &
NUMBA_NUM_THREADS=2 $T --algo sac --env TensegrityRoll-v0 --seed 0 --device cuda --num-threads 2 \
  --log-dir runs_gpu/sac_roll_policy_cuda > runs_gpu/c.log 2>&1 &
NUMBA_NUM_THREADS=2 $T --algo ppo --env TensegrityRoll-v0 --seed 0 --device cuda --num-threads 2 \
  --vec-env torch --env-device cuda --n-envs 4096 -n 3e7 --eval-freq 1000000 --eval-episodes 10 \
  --hyperparams n_steps=32 batch_size=16384 n_epochs=5 \
  --log-dir runs_gpu/ppo_roll_torch_env_4096 > runs_gpu/d.log 2>&1 &
wait
for r in runs_gpu/*/; do n=$(basename $r); tar czf $OUT/$n.tgz --exclude=checkpoints --exclude=tb -C runs_gpu $n; done
tar czf $OUT/logs.tgz runs_gpu/*.log
tail -n 3 runs_gpu/*.log
