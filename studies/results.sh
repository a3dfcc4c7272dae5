#!/usr/bin/env bash
# Everything in results/ that comes from the runs of studies/queue.sh, in one command:
# every trained seed on the 1,000 test seeds, seed spreads, study reports, archiving the best
# seed of each study (chosen on the evaluation set), the noise and latency studies.
# `bash studies/results.sh` after `bash studies/queue.sh` (about 30 minutes on 2 cores). Every
# seed of indep_v5 plays the 1,000 test seeds; the other studies' seeds the first 500.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl}
SEEDS=${SEEDS:-0-999}
[ -d rollouts/ikpd ] || uv run ikpd.py --seeds "$SEEDS" --prefix ikpd
[ -d rollouts/analytic ] || uv run ikpd.py --seeds "$SEEDS" --prefix analytic --controller analytic
for study in indep_v5 indep_v9 noisy delayed curriculum joint collision_v6 collision_v7; do
  [ -d "sweeps/$study/runs" ] || continue
  prefixes=()
  for run in sweeps/"$study"/runs/*/; do
    seed=$(basename "$run" | awk -F__ '{print $2}')
    prefix="${study}_s${seed}"
    seeds=$SEEDS; [ "$study" = indep_v5 ] || seeds=${STUDY_SEEDS:-0-499}
    [ -d "rollouts/$prefix" ] || uv run eval.py --seeds "$seeds" --prefix "$prefix" \
      --model "$run/best_model.zip" > /dev/null
    prefixes+=("$prefix")
  done
  uv run studies/spread.py --prefixes "${prefixes[@]}" --runs sweeps/"$study"/runs/*/ \
    > "results/spread_$study.md"
  uv run studies/sweep.py --report "$study" > "results/sweep_$study.txt"
  [ -f "archive/$study.zip" ] || uv run studies/sweep.py --archive "$study" --archive-as "$study"
done
[ -f results/noise.md ] || uv run studies/robustness.py --question noise --models archive/indep_v5.zip archive/noisy.zip \
  --seeds "${ROBUST_SEEDS:-0-499}"
[ -f results/delay.md ] || uv run studies/robustness.py --question delay --models archive/indep_v5.zip archive/delayed.zip \
  --seeds "${ROBUST_SEEDS:-0-499}"
# The collision-prone subset is found once (5M classical steps) and read back afterwards.
subset=(); [ -f results/collision_seeds.txt ] && subset=(--subset results/collision_seeds.txt)
uv run studies/collision.py --models archive/indep_v5.zip archive/collision_v6.zip \
  archive/collision_v7.zip archive/joint.zip "${subset[@]}"
# Best seed of each study (chosen on the evaluation set) against another: the joint-space
# residual and the curriculum against the Cartesian lead, the lead against the analytic lead.
best_set() {  # the rollout set of a study's archived best seed (or a baseline set as it is)
  case "$1" in ikpd|analytic) echo "$1"; return;; esac
  [ -d "rollouts/$1_best" ] || uv run eval.py --seeds "$SEEDS" --prefix "$1_best" \
    --model "archive/$1.zip" > /dev/null
  echo "$1_best"
}
# (noisy and delayed are compared level by level in noise.md and delay.md: their sidecars
# carry their training noise and delays, so an eval.py rollout of them is in those conditions.)
for pair in "indep_v5 joint" "indep_v5 curriculum" "analytic indep_v5"; do
  set -- $pair
  a=$(best_set "$1"); b=$(best_set "$2")
  uv run metrics.py --prefix-a "$a" --prefix-b "$b" --label-a "$1" --label-b "$2" --breakdown \
    --markdown | awk '/^per seed/{skip=1} skip&&/^$/{skip=0;next} !skip' > "results/$2_vs_$1.md"
done
uv run metrics.py --headline ikpd analytic "$(best_set indep_v5)" \
  --labels Classical Analytic "RL lead (indep_v5)" --plot results/headline_indep_v5.png
