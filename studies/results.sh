#!/usr/bin/env bash
# Every table and figure of the README's Results from the runs of studies/queue.sh, in one
# command: `bash studies/results.sh` (about an hour on 2 cores; each step is skipped when its
# output exists). What only reads committed files (results/runs/) runs from a fresh clone:
# `bash studies/results.sh tables`.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl}
runs() { uv run studies/runs.py "$@"; }
# The headline: the first study of results/studies/rank.md (the lowest mean best evaluation-set error
# over >= 3 seeds, HS) and its chosen run, archived under the run's name (H). At 5 seeds each
# (2026-11-25, queue.sh headline5): `v5_err_decay`, its seed 4, archive/v5_err_decay_s4. The
# previous headline (P), first at 3 seeds: `v5_err_decay_wide_lr3e-4`, its seed 1; before it
# `v5_err_decay` at 3 seeds, its seed 2 (archive/v5_err_decay): the tables that measured those
# models keep their names.
HS=${HEADLINE_STUDY:-v5_err_decay}
H=${HEADLINE:-v5_err_decay_s4}
P=v5_err_decay_wide_lr3e-4
if [ "${1:-all}" = all ]; then
  # 1. One committed summary per training run (config, curve, best model's hash, its metrics
  #    on the 1,000 test seeds), then the baselines at 100 Hz and with the IK at 500 Hz.
  for study in v5 v5_joint climb v5_decay v5_err v5_err_decay v5_err_avg_decay \
      v5_err_decay_smooth v5_track v5_prev v7 delayed_5m noisy_5m ikfree ikfree_long ikfree_5m \
      err_delayed v5_err_decay_wide v5_err_decay_wide_lr3e-4 joint_5m curriculum_5m v9_5m \
      ikfree_50m; do
    [ -d "sweeps/$study/runs" ] && runs summarize --study "$study" --runs sweeps/"$study"/runs/*/
  done
  [ -d sweeps/err_delayed_s3/runs ] && runs summarize --study err_delayed \
    --runs sweeps/err_delayed_s3/runs/*/  # its third seed, a study folder of its own
  for study in joint_5m curriculum_5m v9_5m v5_err_decay_wide_lr3e-4 v5_err_decay ikfree_5m; do
    # their seeds 4-5, study folders of their own (queue.sh side5m, headline5 and main)
    [ -d "sweeps/${study}_s45/runs" ] && runs summarize --study "$study" \
      --runs sweeps/"$study"_s45/runs/*/
  done
  [ -d sweeps/v9_5m_s4/runs ] && runs summarize --study v9_5m --runs sweeps/v9_5m_s4/runs/*/
  [ -f results/runs/baselines.json ] || runs baselines
  # 2. The archived models: v5's chosen run (v5_5m) and the headline, the climb's best study
  #    (the lowest evaluation-set error of all, docs/questions.md 6), each its study's chosen
  #    run (the lowest evaluation-set error, ties to the lower seed).
  [ -f archive/v5_5m.zip ] || runs choose --study v5 --archive-as v5_5m --runs sweeps/v5/runs
  [ -f "archive/$H.zip" ] || runs choose --study "$HS" --archive-as "$H" \
    --runs "sweeps/$HS/runs" "sweeps/${HS}_s45/runs"
  [ -f "archive/$P.zip" ] || runs choose --study "$P" --archive-as "$P" --runs "sweeps/$P/runs"
  S=v5_err_decay_smooth  # the smooth alternative (docs/questions.md 6, the jerk)
  [ -f "archive/$S.zip" ] || runs choose --study "$S" --archive-as "$S" --runs "sweeps/$S/runs"
  for study in ikfree_long ikfree_50m; do  # PPO's health per window (docs/questions.md 7)
    [ -f "results/${study}_diagnostics.csv" ] || [ ! -d "sweeps/$study/runs" ] || runs diagnostics \
      --runs sweeps/"$study"/runs/*/ --csv "results/${study}_diagnostics.csv"
  done
  for seed in 1 2 3; do  # PPO's health with the wider network against the headline's (questions.md 6)
    for study in v5_err_decay v5_err_decay_wide v5_err_decay_wide_lr3e-4; do
      f="results/${study}_s${seed}_diagnostics.csv"
      [ -f "$f" ] || [ ! -d "sweeps/$study/runs" ] || [ -z "$(ls -d sweeps/"$study"/runs/*__"$seed"__*/ 2>/dev/null)" ] || runs diagnostics --runs sweeps/"$study"/runs/*__"$seed"__*/ --csv "$f" \
        --window 1000000
    done
  done
  [ -f archive/ikfree_long.zip ] || runs choose --study ikfree_long --archive-as ikfree_long \
    --runs sweeps/ikfree_long/runs  # no IK, 30M steps (docs/questions.md 7)
  # 3. Rollout sets on the test seeds; the oracle (20 replays per trajectory, started from the
  #    headline's lead) on the first 200.
  [ -d rollouts/classical ] || uv run ikpd.py --seeds 0-999 --prefix classical
  [ -d rollouts/analytic ] || uv run ikpd.py --seeds 0-999 --prefix analytic --controller analytic
  for m in "$H" "$P" v5_err_decay v5_5m indep_v5 ikfree_long; do
    [ -d "rollouts/$m" ] || uv run eval.py --seeds 0-999 --prefix "$m" --model "archive/$m.zip"
  done
  [ -d rollouts/ilc ] || uv run ikpd.py --controller ilc --seeds 0-199 --prefix ilc \
    --model "archive/$H.zip"  # (a new headline: move the old rollouts/ilc aside first)
  # 4. The paired tables and the headline figure.
  for pair in "classical analytic" "classical $H" "analytic $H" "v5_5m $H" "indep_v5 $H" "$P $H" \
      "indep_v5 v5_5m" "$H ikfree_long" "v5_5m ikfree_long" "analytic ikfree_long" \
      "classical ikfree_long"; do
    set -- $pair
    uv run metrics.py --prefix-a "$1" --prefix-b "$2" --breakdown --markdown \
      | awk '/^per seed/{skip=1} skip&&/^$/{skip=0;next} !skip' > "results/$2_vs_$1.md"
  done
  #    the headline's model against the previous headline's (results/<study>_vs_<study>.md is
  #    the two studies' comparison over their seeds, below); the previous headline's own tables
  #    (results/$P_vs_*.md, its oracle) were made with it as H
  uv run metrics.py --prefix-a "$P" --prefix-b "$H" --breakdown --markdown \
    | awk '/^per seed/{skip=1} skip&&/^$/{skip=0;next} !skip' > results/headline/vs_previous_headline.md
  uv run metrics.py --prefix-a analytic --prefix-b "$H" --oracle ilc --markdown \
    > "results/${H}_vs_analytic_with_oracle.md"
  uv run metrics.py --prefix-a analytic --prefix-b v5_5m --oracle ilc --markdown \
    > results/studies/v5/v5_5m_with_oracle.md  # the previous headline against the same oracle
  uv run metrics.py --headline classical analytic v5_5m "$H" ilc --force \
    --labels Classical Analytic "RL lead (v5_5m)" "RL lead ($H)" "ILC oracle" \
    --plot results/headline/headline.png
  # 5. The side studies under the evaluation harness (levels replace a model's own settings);
  #    the latency study's 5M policy (every seed of it at 1 and 3 steps) beside the 1M ones.
  #    They evaluate R, the headline when they were made; the later headlines alone, beside
  #    the same baselines: H in results/robustness_$H/, P in results/history/v5_err_decay_wide_lr3e-4/ (the
  #    folder it was made in, as its headline) (docs/questions.md 1-2).
  R=v5_err_decay
  for q in delay noise; do
    uv run studies/robustness.py --question $q --force --out "results/robustness_$H" \
      --models "archive/$H.zip" --seeds 0-499
    uv run studies/robustness.py --question $q --force --out results/history/v5_err_decay_wide_lr3e-4 \
      --models "archive/$P.zip" --seeds 0-499
  done
  [ -f archive/delayed_5m.zip ] || runs choose --study delayed_5m --archive-as delayed_5m \
    --runs sweeps/delayed_5m/runs
  uv run studies/robustness.py --question delay --force --models archive/indep_v5.zip \
    archive/delayed.zip archive/v5_5m.zip archive/delayed_5m.zip "archive/$R.zip" --seeds 0-499
  #    every seed's model is committed (archive/seeds/, `runs keep`), so these two re-run from git
  for study in delayed_5m err_delayed; do
    [ -d "sweeps/$study/runs" ] && runs keep --study "$study" --runs sweeps/"$study"*/runs
  done
  uv run studies/robustness.py --question delay --levels 1 3 --out results/studies/delay/delayed_5m_seeds --force \
    --models archive/seeds/delayed_5m_s*.zip --seeds 0-499
  #    the headline's configuration trained with delay (3 seeds), beside delayed_5m's chosen seed
  uv run studies/robustness.py --question delay --force --out results/studies/delay/err_delayed \
    --models archive/delayed_5m.zip "archive/$R.zip" archive/seeds/err_delayed_s*.zip --seeds 0-499
  [ -f archive/noisy_5m.zip ] || runs choose --study noisy_5m --archive-as noisy_5m \
    --runs sweeps/noisy_5m/runs
  [ -d sweeps/noisy_5m/runs ] && runs keep --study noisy_5m --runs sweeps/noisy_5m/runs
  uv run studies/robustness.py --question noise --force --models archive/indep_v5.zip \
    archive/noisy.zip archive/v5_5m.zip archive/noisy_5m.zip "archive/$R.zip" \
    "archive/$S.zip" --seeds 0-499
  uv run studies/robustness.py --question noise --levels 1 2 --out results/studies/noise/noisy_5m_seeds --force \
    --models archive/seeds/noisy_5m_s*.zip --seeds 0-499
  [ -f archive/v7_5m.zip ] || runs choose --study v7 --archive-as v7_5m --runs sweeps/v7/runs
  uv run studies/collision.py --force --models archive/indep_v5.zip archive/collision_v6.zip \
    archive/collision_v7.zip archive/joint.zip archive/v5_5m.zip archive/v7_5m.zip \
    --subset results/studies/collision/collision_seeds.txt
  uv run studies/collision.py --force --models archive/v5_5m.zip archive/v7_5m.zip \
    --subset results/studies/collision/collision_seeds.txt --out results/studies/collision/collision_5m.md  # v7 against v5, both 5M
  #    every v7 seed (committed, `runs keep`) against v5_5m's model (v5's 5M run folders are gone)
  [ -d sweeps/v7/runs ] && runs keep --study v7 --runs sweeps/v7/runs
  uv run studies/collision.py --force --models archive/v5_5m.zip archive/seeds/v7_s*.zip \
    --subset results/studies/collision/collision_seeds.txt --out results/studies/collision/v7_seeds/collision.md
  #    the joint residual at 5M (its chosen seed; seeds 4-5 ran in a folder of their own)
  [ -f archive/joint_5m.zip ] || runs choose --study joint_5m --archive-as joint_5m \
    --runs sweeps/joint_5m/runs sweeps/joint_5m_s45/runs
  uv run studies/collision.py --force --models archive/v5_5m.zip archive/joint_5m.zip \
    --subset results/studies/collision/collision_seeds.txt --out results/studies/collision/collision_joint_5m.md
fi
# From committed files only: the spread tables and the paired study comparisons.
for study in v5 v5_joint climb v5_err_decay_wide_lr3e-4; do
  [ -d "results/runs/$study" ] && runs report --study "$study" > "results/spread_$study.md"
done
runs rank > results/studies/rank.md  # the headline rule, applied to every study (selection data only)
runs rates --study "$HS" > results/headline/rates_500hz.md
runs compare --study v5_joint --against-study v5 > results/studies/v5_joint/vs_v5.md
[ -d results/runs/v7 ] && runs compare --study v7 --against-study v5_joint > results/studies/v7/vs_v5_joint.md
[ -d results/runs/err_delayed ] && runs report --study err_delayed > results/studies/err_delayed/spread.md \
  && runs compare --study err_delayed --against-study delayed_5m > results/studies/err_delayed/vs_delayed_5m.md
[ -d results/runs/climb ] && runs compare --study climb --against-study v5 > results/studies/climb/vs_v5.md
for study in v5_decay v5_err v5_err_decay v5_err_avg_decay v5_err_decay_smooth v5_track v5_prev \
    v7 delayed_5m noisy_5m v5_err_decay_wide joint_5m curriculum_5m v9_5m; do
  [ -d "results/runs/$study" ] || continue
  runs report --study "$study" > "results/spread_$study.md"
  runs compare --study "$study" --against-study v5 > "results/${study}_vs_v5.md"
done
# the IK-free policy: the long run against ikfree's 5M, and its curve beside the lead's (docs/questions.md 7)
if [ -d results/runs/ikfree_long ]; then
  runs compare --study ikfree_long --against-study ikfree > results/studies/ikfree_long/vs_ikfree.md
  [ -d results/runs/ikfree_5m ] && runs report --study ikfree_5m > results/studies/ikfree_5m/spread.md
  [ -d results/runs/ikfree_50m ] && runs report --study ikfree_50m > results/studies/ikfree_50m/spread.md \
    && runs compare --study ikfree_50m --against-study ikfree_long > results/studies/ikfree_50m/vs_ikfree_long.md
  for lead in "$HS" "$P"; do  # against the headline's study and the previous headline's
    for study in ikfree_5m ikfree_50m; do
      [ -d "results/runs/$study" ] && runs compare --study "$study" --against-study "$lead" \
        > "results/${study}_vs_$lead.md"
    done
  done
  long=ikfree_long; [ -d results/runs/ikfree_50m ] && long="ikfree_50m ikfree_long"
  runs curve --studies $long ikfree "$HS" --plot results/studies/ikfree_long/curve.png \
    --stopped results/studies/ikfree_long/stopped_const_lr_diagnostics.csv results/studies/ikfree_long/stopped_err_lr1e-3_diagnostics.csv
fi
# the speed curriculum's question is time to quality: its curve beside v5's (questions.md 5)
[ -d results/runs/curriculum_5m ] && runs curve --studies curriculum_5m v5 \
  --plot results/studies/curriculum_5m/curve.png > results/studies/curriculum_5m/curve.md  # + its steps to quality
# the climb's steps against the step before them (each changes one thing)
for pair in "v5_err_decay v5_err" "v5_err_decay v5_decay" "v5_err_avg_decay v5_err_decay" \
    "v5_err_decay_smooth v5_err_decay" "v5_err_decay_wide v5_err_decay" \
    "v5_err_decay_wide_lr3e-4 v5_err_decay"; do
  set -- $pair
  [ -d "results/runs/$1" ] && [ -d "results/runs/$2" ] || continue
  runs compare --study "$1" --against-study "$2" > "results/$1_vs_$2.md"
done
exit 0
