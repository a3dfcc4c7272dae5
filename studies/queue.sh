#!/usr/bin/env bash
# The training runs behind docs/results.md and docs/questions.md, one after another, as
# Optuna grid studies (`bash studies/queue.sh`, about 55 minutes on 2 cores: 26 runs of 1M
# steps, about 2 minutes each). Each study's runs
# are under sweeps/<name>/runs/; `uv run studies/sweep.py --report NAME` summarises one and
# `--archive NAME --archive-as X` archives its best seed, chosen on the evaluation set.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl}
T=${TIMESTEPS:-1000000}
sweep() { uv run studies/sweep.py --timesteps "$T" "$@"; }
sweep --name indep_v5 --presets v5 --seeds 1 2 3 4 5
sweep --name noisy --presets v5 --seeds 1 2 3 \
  --train-args="--env.obs-noise ee_pos 0.01 target_pos 0.01 ee_vel 0.1 target_vel 0.1 target_acc 1.0"
sweep --name delayed --presets v5 --seeds 1 2 3 \
  --train-args="--env.obs-delay 3 --env.action-delay 3 --env.random-delay"
sweep --name collision_v6 --presets v6 --seeds 1 2 3
sweep --name collision_v7 --presets v7 --seeds 1 2 3
sweep --name curriculum --presets v5 --seeds 1 2 3 --train-args="--curriculum-steps 500000"
sweep --name joint --presets joint --seeds 1 2 3
sweep --name indep_v9 --presets v9 --seeds 1 2 3
