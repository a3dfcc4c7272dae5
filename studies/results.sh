#!/usr/bin/env bash
# Everything in results/ that comes from the runs of studies/queue.sh, in one command:
# every trained seed on the 1,000 test seeds, seed spreads, study reports, archiving the best
# seed of each study (chosen on the evaluation set), the noise and latency studies.
# `bash studies/results.sh` after `bash studies/queue.sh` (about 25 minutes on 2 cores).
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl}
SEEDS=${SEEDS:-0-999}
[ -d rollouts/ikpd ] || uv run ikpd.py --seeds "$SEEDS" --prefix ikpd
[ -d rollouts/analytic ] || uv run ikpd.py --seeds "$SEEDS" --prefix analytic --controller analytic
for study in indep_v5 indep_v9 noisy delayed curriculum; do
  [ -d "sweeps/$study/runs" ] || continue
  prefixes=()
  for run in sweeps/"$study"/runs/*/; do
    seed=$(basename "$run" | awk -F__ '{print $2}')
    prefix="${study}_s${seed}"
    [ -d "rollouts/$prefix" ] || uv run eval.py --seeds "$SEEDS" --prefix "$prefix" \
      --model "$run/best_model.zip" > /dev/null
    prefixes+=("$prefix")
  done
  uv run studies/spread.py --prefixes "${prefixes[@]}" --runs sweeps/"$study"/runs/*/ \
    > "results/spread_$study.md"
  uv run studies/sweep.py --report "$study" > "results/sweep_$study.txt"
  [ -f "archive/$study.zip" ] || uv run studies/sweep.py --archive "$study" --archive-as "$study"
done
uv run studies/robustness.py --question noise --models archive/indep_v5.zip archive/noisy.zip \
  --seeds "${ROBUST_SEEDS:-0-499}"
uv run studies/robustness.py --question delay --models archive/indep_v5.zip archive/delayed.zip \
  --seeds "${ROBUST_SEEDS:-0-499}"
