#!/bin/bash
# five training seeds of results/ppo_shape_force_density_vertical at once on the lent 16-core machine
set -u
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=3 MKL_NUM_THREADS=3 NUMBA_NUM_THREADS=3
mkdir -p runs_seeds
for s in 0 1 2 3 4; do
  python3 -m agents.train --algo ppo --env TensegrityShape-v0 --seed $s -n 1e6 --n-envs 64 \
    --env-kwargs action_mode:force_density 'actuated:[6, 7, 8]' --hyperparams n_steps=64 --eval-freq 100000 \
    --eval-episodes 20 --num-threads 3 --log-dir runs_seeds/ppo_shape_fdv_s$s --no-progress-bar --max-wall-time 190 \
    > runs_seeds/s$s.log 2>&1 &
done
wait
tar czf $OUT/seeds.tgz --exclude=checkpoints --exclude=tb --exclude=replay_buffer.pkl runs_seeds
tail -n 1 runs_seeds/*.log
