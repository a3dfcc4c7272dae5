#!/usr/bin/env bash
# The training runs behind docs/results.md and docs/questions.md (independent training seeds),
# one after another: `bash studies/queue.sh` (about an hour on 2 cores). Each run's folder is
# under runs/indep/; best.json in it holds its evaluation-set error (used for selection).
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl}
T=${TIMESTEPS:-1000000}
NOISE=(--env.obs-noise ee_pos 0.01 target_pos 0.01 ee_vel 0.1 target_vel 0.1 target_acc 1.0)
DELAY=(--env.obs-delay 3 --env.action-delay 3 --env.random-delay)
for s in 1 2 3 4 5; do uv run train.py --preset v5 --seed $s --timesteps $T --name v5 --runs-dir runs/indep --no-progress; done
for s in 1 2 3; do uv run train.py --preset v5 --seed $s --timesteps $T --name noisy "${NOISE[@]}" --runs-dir runs/indep --no-progress; done
for s in 1 2 3; do uv run train.py --preset v5 --seed $s --timesteps $T --name delayed "${DELAY[@]}" --runs-dir runs/indep --no-progress; done
for s in 1 2 3 4 5; do uv run train.py --preset v9 --seed $s --timesteps $T --name v9 --runs-dir runs/indep --no-progress; done
