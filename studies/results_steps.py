"""The steps of `studies/results.py`: every table and figure under results/ that a command
remakes, the command, and what it reads. Read by results.py; the headline's and the hardware
model's names are panda_lead/roles.py's.

A step's command is an argument list run with the repo's Python (shown as `uv run ...`).
`{out0}`, `{out1}`... stand for its outputs and `{dir}` for their folder: the step runs with
them pointing into a scratch folder and its files are moved into place only when it succeeds.
A step whose `stdout` is set writes its first output from the command's standard output.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

from panda_lead.roles import HARDWARE, HEADLINE  # noqa: F401  (re-exported to results_*.py)

ROOT = Path(__file__).resolve().parents[1]

# The headline: by issue 37's rule (docs/training.md), the presets' budget's first study on
# the selection set and its first model there, archived under the run's name. From 2026-11-27:
# the headline preset's study retrained with its seeds kept, `v5_err_decay_kept`, its seed 3.
# Its name, and the hardware model's, live in panda_lead/roles.py (the cards say the roles).
# When it moves, move results/headline/'s model tables to results/history/<old>/
# (history/README.md) and rerun.
HEADLINE_STUDY = "v5_err_decay_kept"
# the headline's preset's first study (2026-11-24/25): the study-level comparisons quote it
PRESET_STUDY = "v5_err_decay"
PREVIOUS_HEADLINE = "v5_err_decay_s4"  # the headline before (its tables: history/); issue 36's
PREVIOUS = "v5_err_decay_wide_lr3e-4"  # the one before that, a study of its own too
ROBUST = "v5_err_decay"  # the model the multi-model latency/noise tables measured (seed 2)
# studies whose archived seed is chosen by issue 37's rule on the selection set (runs.py
# --by selection); the rest keep the rule they were archived by, the best of 15 evaluation
# trajectories
BY_SELECTION = {HEADLINE_STUDY, "deploy_caps_armfilter_5m", "deploy_large_batch_5m",
                "deploy_large_batch_wide_5m", "deploy_large_batch_continued_5m",
                "v5_err_decay_preview_continued_5m", "deploy_large_batch_curv10_continued_5m",
                "deploy_large_batch_curv10_actions_continued_5m",
                "deploy_large_batch_curv10_actions_stack4_continued_5m",
                "deploy_large_batch_curv10_actions_stack8_continued_5m",
                "deploy_large_batch_curv10_actions_stack4_continued_again_5m",
                "deploy_large_batch_curv10_actions_stack4_finetuned_5m",
                "v5_err_decay_preview_finetuned_5m",
                "deploy_large_batch_curv10_actions_stack4_finetuned_n50_5m",
                "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m",
                "preview_feedforward_5m", "v5_err_decay_repetitive_5m",
                "v5_err_decay_repetitive_finetuned_5m"}
# The device pilots on the deployment world's share of nominal episodes (archive/seeds/<name>
# models, each paired with the next on the test seeds): the headline's preset, the deployment
# world on nominal episodes alone, 3 in 4, 1 in 2, then 1 in 2 under the cpu profile.
SHARE_LADDER = ["gpu_v5_err_decay_5m_s3", "gpu_deploy_nominal_only_5m_s3",
                "gpu_deploy_nominal75_5m_s3", "gpu_deploy_caps_armfilter_5m_s3",
                "deploy_caps_armfilter_5m_s3"]
SMOOTH = "v5_err_decay_smooth"  # the smooth alternative (docs/questions.md 6, the jerk)
DEPLOY_STUDY = "deploy_lowpass_5m"  # issue 36's study (docs/questions.md 10)
DEPLOY = "deploy_lowpass_5m"  # its chosen seed, archived
COLLISION_SEEDS = "results/studies/collision/collision_seeds.txt"
# the hardware study's fine-tune trained with the planner's hand in the loop (follow_plan)
LATE100_HAND = "deploy_large_batch_curv10_actions_stack4_finetuned_late100_plan_5m"


@dataclass(frozen=True)
class Step:
    outs: tuple[str, ...]
    """What it writes (repo-relative files under results/)."""
    argv: tuple[str, ...]
    """The command, without `uv run`: a script and its flags."""
    inputs: tuple[str, ...] = ()
    """The files and folders it reads: a change in any of them makes its outputs stale."""
    stdout: bool = False
    """outs[0] is the command's standard output."""
    per_seed_dropped: bool = False
    """Drop metrics.py --breakdown's long per-seed section from the table."""
    section: str = "tables"
    """"tables": reads only committed files (results/runs/), minutes; "all": needs the runs'
    rollout sets or sweeps, or evaluates models (an hour or more on 2 cores)."""


def _runs(*names: str) -> tuple[str, ...]:
    return tuple(f"results/runs/{n}" for n in names)


def _report(study: str) -> Step:
    """A study's spread, its chosen seed marked by the rule its archive was chosen by."""
    if study in BY_SELECTION:
        # It reads its own seeds' selection scores only: another study's new score must not
        # make it stale (it did while the input was the whole scores folder).
        scores = sorted(f"results/studies/rank/scores/{f.name}" for f in
                        (ROOT / "results/studies/rank/scores").glob(f"{study}_s[0-9]*.json"))
        return Step((f"results/studies/{study}/spread.md",),
                    ("studies/runs.py", "report", "--study", study, "--by", "selection"),
                    (*_runs(study, "baselines.json"), *scores), stdout=True)
    return Step((f"results/studies/{study}/spread.md",),
                ("studies/runs.py", "report", "--study", study),
                _runs(study, "baselines.json"), stdout=True)


def _compare(study: str, against: str) -> Step:
    return Step((f"results/studies/{study}/vs_{against}.md",),
                ("studies/runs.py", "compare", "--study", study, "--against-study", against),
                _runs(study, against), stdout=True)


def _pair(a: str, b: str, out: str, *extra: str) -> Step:
    """metrics.py's paired table, B against A, from the rollout sets of the test seeds (with
    metrics.py's ``extra`` flags)."""
    return Step((out,), ("metrics.py", "--prefix-a", a, "--prefix-b", b, "--breakdown", *extra,
                         "--markdown"), (f"rollouts/{a}", f"rollouts/{b}"), stdout=True,
                per_seed_dropped=True, section="all")


def _summary(out: str, pairs: list[tuple[str, str]], names: tuple[str, str] | None = None,
             paired: bool = False, extra: tuple[str, ...] = ()) -> Step:
    """online_correction.py summary's table of a five-seed study's pairs of rollout sets (A, B)
    on the test seeds, B minus A with a two-level bootstrap (and a seed-paired one; ``extra``:
    its other flags)."""
    argv = ("studies/online_correction.py", "summary", "--pairs",
            *(f"{a}:{b}" for a, b in pairs), *(("--names", *names) if names else ()),
            *(("--paired-seeds",) if paired else ()), *extra)
    inputs = tuple(dict.fromkeys(f"rollouts/{x}" for pair in pairs for x in pair))
    return Step((out,), argv, inputs, stdout=True, section="all")


ROWS = ("none", "delay1", "delay3", "camera3", "noise1", "noise2")
# every default row of studies/deploy.py (its DEFAULT_CONDITIONS): a hardware candidate's table
EVERY_ROW = ("none", "delay1", "delay3", "camera1", "camera3", "noise1", "noise2")


def _deploy(models: list[str], out_dir: str, conditions: tuple[str, ...] = ROWS,
            seeds: str = "0-99", *extra: str, studies: tuple[str, str] | None = None) -> Step:
    """studies/deploy.py's table and figure for these models on test seeds 0-99 (or others);
    with ``studies`` (A, B) the command names the two studies (--studies: both studies' seeds'
    rows and B minus A), ``models`` being their seeds' files, what the step reads."""
    pick = ("--studies", *studies) if studies else ("--models", *models)
    return Step((f"{out_dir}/deploy.md", f"{out_dir}/deploy.png"),
                ("studies/deploy.py", *pick, "--seeds", seeds, "--conditions",
                 *conditions, *extra, "--out", "{dir}"), tuple(models), section="all")


def _deploy_studies(a: str, b: str, out_dir: str, conditions: tuple[str, ...],
                    seeds: str, *extra: str) -> Step:
    """_deploy for two five-seed studies, A then B."""
    models = [f"archive/seeds/{st}_s{k}.zip" for st in (a, b) for k in range(1, 6)]
    return _deploy(models, out_dir, conditions, seeds, *extra, studies=(a, b))


def _five_seeds(study: str, against: str) -> list[Step]:
    """A five-seed study's spread, its comparison with another study (paired per trajectory)
    and every seed's deployability rows (results/studies/<study>/)."""
    models = [f"archive/seeds/{study}_s{k}.zip" for k in range(1, 6)]
    return [_report(study), _compare(study, against),
            _deploy(models, f"results/studies/{study}")]


def _study_against(study: str, control: str) -> list[Step]:
    """A five-seed deployment study against its control: _five_seeds, and both studies' ten
    seeds' acceptance on all 1,000 test seeds without delay and at 1 and 3 steps of latency
    (two-level bootstrap, checked from 0.5 and 0.75 s: results/studies/<study>/test1000/)."""
    return _five_seeds(study, control) + [
        _deploy_studies(control, study, f"results/studies/{study}/test1000",
                        ("none", "delay1", "delay3"), "0-999", "--check-from", "0.75")]


def _every_row(study: str, model: str, previous: str) -> Step:
    """An archived model beside the one it would replace, every deployment row on all 1,000
    test seeds (results/studies/<study>/lowpass1000/)."""
    return _deploy([f"archive/{model}.zip", f"archive/{previous}.zip"],
                   f"results/studies/{study}/lowpass1000", EVERY_ROW, "0-999",
                   "--check-from", "0.75")


def _oracle_table(out: str, model: str, oracle: str) -> Step:
    """A model against the analytic lead and the ILC oracle restarted from it, the share of the
    oracle's gain it captures overall and per shape (--breakdown, its per-seed rows dropped)."""
    return Step((out,), ("metrics.py", "--prefix-a", "analytic", "--prefix-b", model,
                         "--oracle", oracle, "--breakdown", "--markdown"),
                ("rollouts/analytic", f"rollouts/{model}", f"rollouts/{oracle}"), stdout=True,
                per_seed_dropped=True, section="all")


def _with_oracle(study: str, model: str, oracle: str) -> Step:
    """_oracle_table for a study's chosen model (results/studies/<study>/with_oracle.md)."""
    return _oracle_table(f"results/studies/{study}/with_oracle.md", model, oracle)


def _robust(question: str, models: list[str], out_dir: str, *extra: str) -> Step:
    return Step((f"{out_dir}/{question}.md", f"{out_dir}/{question}.png"),
                ("studies/robustness.py", "--question", question, "--models", *models,
                 "--seeds", "0-499", *extra, "--out", "{dir}"), tuple(models), section="all")


def _collision(models: list[str], out: str) -> Step:
    """collision.py writes the subset's seeds beside its table (<out stem>_seeds.txt)."""
    return Step((out, out.replace(".md", "_seeds.txt")),
                ("studies/collision.py", "--models", *models, "--subset", COLLISION_SEEDS,
                 "--out", "{out0}"), (*models, COLLISION_SEEDS), section="all")


def table_steps() -> list[Step]:
    H, HS, P, R, S = HEADLINE, PRESET_STUDY, PREVIOUS, ROBUST, SMOOTH
    hd = "results/headline"
    steps = [
        # from committed files only: spread tables and study comparisons
        Step(("results/studies/rank.md",), ("studies/runs.py", "rank"), ("results/runs",),
             stdout=True),
        Step((f"{hd}/rates_500hz.md",), ("studies/runs.py", "rates", "--study", HS),
             _runs(HS, "baselines.json") + ("results/studies/tau/tau_500hz.txt",), stdout=True),
    ]
    for study in ["v5", "v5_joint", "climb", "v5_decay", "v5_err", "v5_err_decay",
                  "v5_err_avg_decay", "v5_err_decay_smooth", "v5_err_decay_wide",
                  "v5_err_decay_wide_lr3e-4", "v7", "delayed_5m", "err_delayed", "noisy_5m",
                  "joint_5m", "curriculum_5m", "v9_5m", "ikfree_5m", "ikfree_50m"]:
        steps.append(_report(study))
    for study in ["v5_joint", "climb", "v5_decay", "v5_err", "v5_err_decay", "v5_err_avg_decay",
                  "v5_err_decay_smooth", "v5_err_decay_wide", "v7", "delayed_5m", "noisy_5m",
                  "joint_5m", "curriculum_5m", "v9_5m"]:
        steps.append(_compare(study, "v5"))
    for study, against in [("v7", "v5_joint"), ("err_delayed", "delayed_5m"),
                           ("v5_err_decay", "v5_err"), ("v5_err_decay", "v5_decay"),
                           ("v5_err_avg_decay", "v5_err_decay"),
                           ("v5_err_decay_smooth", "v5_err_decay"),
                           ("v5_err_decay_wide", "v5_err_decay"), (P, "v5_err_decay"),
                           ("ikfree_long", "ikfree"), ("ikfree_50m", "ikfree_long"),
                           ("ikfree_5m", HS), ("ikfree_50m", HS), ("ikfree_5m", P),
                           ("ikfree_50m", P)]:
        steps.append(_compare(study, against))
    # the headline's preset retrained with its seeds kept (2026-11-27, an AMD EPYC; the study
    # itself on 2026-11-24/25's machines): what another CPU family's draw of the same five
    # training seeds gives
    steps += [_report("v5_err_decay_kept"), _compare("v5_err_decay_kept", HS)]
    # ... and with the policy's own last 6 actions observed (recent_actions), against it
    steps += [_report("v5_err_decay_actions_5m"),
              _compare("v5_err_decay_actions_5m", "v5_err_decay_kept")]
    stopped = ("results/studies/ikfree_long/stopped_const_lr_diagnostics.csv",
               "results/studies/ikfree_long/stopped_err_lr1e-3_diagnostics.csv")
    steps += [
        Step(("results/studies/ikfree_long/curve.png",),
             ("studies/runs.py", "curve", "--studies", "ikfree_50m", "ikfree_long", "ikfree", HS,
              "--plot", "{out0}", "--stopped", *stopped),
             _runs("ikfree_50m", "ikfree_long", "ikfree", HS) + stopped),
        # the speed curriculum's question is time to quality: its curve beside v5's, and its
        # steps to quality (the table is the command's output)
        Step(("results/studies/curriculum_5m/curve.md",
              "results/studies/curriculum_5m/curve.png"),
             ("studies/runs.py", "curve", "--studies", "curriculum_5m", "v5", "--plot", "{out1}"),
             _runs("curriculum_5m", "v5"), stdout=True),
    ]
    # PPO's health per window, from the run folders (not committed; a `*` is expanded)
    for study in ["ikfree_long", "ikfree_50m"]:
        steps.append(Step((f"results/studies/{study}/diagnostics.csv",),
                          ("studies/runs.py", "diagnostics", "--runs", f"sweeps/{study}/runs/*/",
                           "--csv", "{out0}"), (f"sweeps/{study}/runs",), section="all"))
    for study, seeds in [("v5_err_decay", (1, 2, 3)), ("v5_err_decay_wide", (1, 2, 3)),
                         (P, (3,))]:  # the wider network's health against the headline's
        for k in seeds:
            steps.append(Step((f"results/studies/{study}/s{k}_diagnostics.csv",),
                              ("studies/runs.py", "diagnostics", "--runs",
                               f"sweeps/{study}/runs/*__{k}__*/", "--csv", "{out0}",
                               "--window", "1000000"), (f"sweeps/{study}/runs",), section="all"))
    # the headline's paired tables, its oracle and the headline figure
    steps += [
        _pair("classical", "analytic", f"{hd}/analytic_vs_classical.md"),
        _pair("classical", H, f"{hd}/vs_classical.md"),
        _pair("analytic", H, f"{hd}/vs_analytic.md"),
        _pair("v5_5m", H, f"{hd}/vs_v5_5m.md"),
        _pair("indep_v5", H, f"{hd}/vs_indep_v5.md"),
        _pair(PREVIOUS_HEADLINE, H, f"{hd}/vs_previous_headline.md"),
        _pair("indep_v5", "v5_5m", "results/studies/v5/v5_5m_vs_indep_v5.md"),
        _oracle_table(f"{hd}/with_oracle.md", H, "ilc"),
        Step((f"{hd}/headline.png",),
             ("metrics.py", "--headline", "classical", "analytic", "v5_5m", H, "ilc", "--labels",
              "Classical", "Analytic", "RL lead (v5_5m)", f"RL lead ({H})", "ILC oracle",
              "--plot", "{out0}"),
             ("rollouts/classical", "rollouts/analytic", "rollouts/v5_5m", f"rollouts/{H}",
              "rollouts/ilc"), section="all"),
    ]
    for b in [PREVIOUS_HEADLINE, "v5_5m", "analytic", "classical"]:  # (the headline then)
        steps.append(_pair(b, "ikfree_long", f"results/studies/ikfree_long/ikfree_long_vs_{b}.md"))
    # latency and noise under the evaluation harness (levels replace a model's own settings)
    a = "archive/"
    steps += [
        _robust("delay", [f"{a}{H}.zip"], hd), _robust("noise", [f"{a}{H}.zip"], hd),
        _robust("delay", [f"{a}indep_v5.zip", f"{a}delayed.zip", f"{a}v5_5m.zip",
                          f"{a}delayed_5m.zip", f"{a}{R}.zip"], "results/studies/delay"),
        _robust("delay", [f"{a}seeds/delayed_5m_s{k}.zip" for k in range(1, 6)],
                "results/studies/delay/delayed_5m_seeds", "--levels", "1", "3"),
        _robust("delay", [f"{a}delayed_5m.zip", f"{a}{R}.zip"]
                + [f"{a}seeds/err_delayed_s{k}.zip" for k in range(1, 4)],
                "results/studies/delay/err_delayed"),
        _robust("noise", [f"{a}indep_v5.zip", f"{a}noisy.zip", f"{a}v5_5m.zip",
                          f"{a}noisy_5m.zip", f"{a}{R}.zip", f"{a}{S}.zip"],
                "results/studies/noise"),
        _robust("noise", [f"{a}seeds/noisy_5m_s{k}.zip" for k in range(1, 6)],
                "results/studies/noise/noisy_5m_seeds", "--levels", "1", "2"),
        # self-collision on the collision-prone trajectories of the seed pool
        _collision([f"{a}indep_v5.zip", f"{a}collision_v6.zip", f"{a}collision_v7.zip",
                    f"{a}joint.zip", f"{a}v5_5m.zip", f"{a}v7_5m.zip"],
                   "results/studies/collision/collision.md"),
        _collision([f"{a}v5_5m.zip", f"{a}v7_5m.zip"], "results/studies/collision/collision_5m.md"),
        _collision([f"{a}v5_5m.zip"] + [f"{a}seeds/v7_s{k}.zip" for k in range(1, 6)],
                   "results/studies/collision/v7_seeds/collision.md"),
        _collision([f"{a}v5_5m.zip", f"{a}joint_5m.zip"],
                   "results/studies/collision/collision_joint_5m.md"),
    ]
    # issue 37, the path ahead (a labelled variant: "knows the planned path")
    pv = "results/studies/preview"
    steps += [
        Step((f"{pv}/spread.md",), ("studies/runs.py", "report", "--study", "preview_5m"),
             _runs("preview_5m", "baselines.json"), stdout=True),
        Step((f"{pv}/preview_5m_vs_{HS}.md",),
             ("studies/runs.py", "compare", "--study", "preview_5m", "--against-study", HS),
             _runs("preview_5m", HS), stdout=True),
    ]
    # the preview lead's share of the oracle's gain, the oracle restarted from it (0-199)
    steps.append(_oracle_table(f"{pv}/preview_5m_with_oracle.md", "preview_5m", "ilc_preview"))
    # issue 37's selection rule: every scored model and study on the selection set
    steps.append(Step(("results/studies/rank/rank.md",), ("studies/selection.py", "rank"),
                      ("results/studies/rank/scores",), stdout=True))
    # the preview study against the classical rivals given the same path (test seeds 0-999)
    steps += [Step((f"{pv}/preview_5m_vs_{rival}.md",),
                   ("studies/runs.py", "compare", "--study", "preview_5m", "--against-study",
                    f"baseline:{rival}"), _runs("preview_5m", "baselines.json"), stdout=True)
              for rival in ("feedforward", "future_target")]
    steps.append(Step((f"{pv}/feedforward_vs_analytic_1000.md",),
                      ("studies/runs.py", "compare", "--study", "baseline:feedforward",
                       "--against-study", "baseline:analytic"), _runs("baselines.json"),
                      stdout=True))
    steps.append(Step((f"{pv}/{HS}_vs_feedforward.md",),
                      ("studies/runs.py", "compare", "--study", HS, "--against-study",
                       "baseline:feedforward"), _runs(HS, "baselines.json"), stdout=True))
    # which test episodes the arm can follow all the way (feedforward_plan hands those over)
    steps.append(Step((f"{pv}/followable.md",), ("studies/preview_rivals.py", "--followable",
                                                  "0-999"), (), stdout=True))
    # the feedforward that follows its plan open-loop where the arm can (the stronger rival:
    # results/studies/preview/rivals_tuning_plan.md), against the feedforward, the preset's
    # study and the hardware study (each alone, per shape: where the plan is followable)
    late = "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m"
    steps.append(Step((f"{pv}/feedforward_plan_vs_feedforward.md",),
                      ("studies/runs.py", "compare", "--study", "baseline:feedforward_plan",
                       "--against-study", "baseline:feedforward", "--by-shape"),
                      _runs("baselines.json"), stdout=True))
    steps += [Step((out,), ("studies/runs.py", "compare", "--study", study, "--against-study",
                            "baseline:feedforward_plan", "--by-shape"),
                   _runs(study, "baselines.json"), stdout=True)
              for study, out in ((HS, f"{pv}/{HS}_vs_feedforward_plan.md"),
                                 (late, f"results/studies/{late}/vs_feedforward_plan.md"))]
    # the learned residual on the feedforward rival (issue 37; knows the planned path)
    for study in ("preview_feedforward_5m", "preview_feedforward_settled_5m"):
        out = f"results/studies/{study}"
        steps += [_report(study), _compare(study, "preview_5m"), _compare(study, HS),
                  Step((f"{out}/vs_feedforward.md",),
                       ("studies/runs.py", "compare", "--study", study, "--against-study",
                        "baseline:feedforward"), _runs(study, "baselines.json"), stdout=True)]
    steps.append(_compare("preview_feedforward_settled_5m", "preview_feedforward_5m"))
    steps.append(Step(("results/studies/preview_feedforward_5m/vs_feedforward_by_shape.md",),
                      ("studies/runs.py", "compare", "--study", "preview_feedforward_5m",
                       "--against-study", "baseline:feedforward", "--by-shape"),
                      _runs("preview_feedforward_5m", "baselines.json"), stdout=True))
    # the path ahead once the causal lead is learned: the headline study's seeds trained on
    # with it and without it (the control), against each other, their start and the rival
    # (and the same pair again with a gentle restart: the seeds' own exploration, lr 3e-4)
    cont, pcont = "v5_err_decay_continued_5m", "v5_err_decay_preview_continued_5m"
    for study in (cont, pcont, "v5_err_decay_finetuned_5m", "v5_err_decay_preview_finetuned_5m"):
        steps += [_report(study), _compare(study, "v5_err_decay_kept"),
                  Step((f"results/studies/{study}/vs_feedforward.md",),
                       ("studies/runs.py", "compare", "--study", study, "--against-study",
                        "baseline:feedforward"), _runs(study, "baselines.json"), stdout=True)]
    steps += [_compare(pcont, cont),
              _compare("v5_err_decay_preview_finetuned_5m", "v5_err_decay_finetuned_5m"),
              _compare("v5_err_decay_finetuned_5m", cont)]
    # what the path ahead buys per target shape (a causal lead cannot see a spline's future):
    # each preview study against the causal study it is paired with
    for study, against in (("preview_5m", HS), (pcont, cont),
                           ("v5_err_decay_preview_finetuned_5m", "v5_err_decay_finetuned_5m")):
        out = (f"results/studies/preview/preview_5m_vs_{against}_by_shape.md"
               if study == "preview_5m" else f"results/studies/{study}/vs_{against}_by_shape.md")
        steps.append(Step((out,),
                          ("studies/runs.py", "compare", "--study", study, "--against-study",
                           against, "--by-shape"), _runs(study, against), stdout=True))
    # ... and each chosen model's share of the oracle's gain, the oracle restarted from it
    # (the wide restart's and the gentle one's)
    steps += [_with_oracle(pcont, "preview_continued_10m", "ilc_preview_continued"),
              _with_oracle("v5_err_decay_preview_finetuned_5m", "preview_finetuned_10m",
                           "ilc_preview_finetuned")]
    steps.append(Step((f"results/studies/{pcont}/vs_future_target.md",),
                      ("studies/runs.py", "compare", "--study", pcont, "--against-study",
                       "baseline:future_target"), _runs(pcont, "baselines.json"), stdout=True))
    # issue 36, a lead a real arm could run: the study, and the deployability table
    steps += [_report(DEPLOY_STUDY), _compare(DEPLOY_STUDY, "delayed_5m"),
              _compare(DEPLOY_STUDY, HS)]
    # the pilots toward one lead with no trade-off (docs/deploy.md): the best one's seeds and
    # its step from deploy_real, paired by training seed
    steps += [_report("deploy_nominal_5m"), _compare("deploy_nominal_5m", "deploy_real_5m")]
    # the filter on the tip's readings too (a pilot), against deploy_nominal
    steps += [_report("deploy_armfilter_5m"), _compare("deploy_armfilter_5m", "deploy_nominal_5m")]
    pair = [f"{a}seeds/deploy_nominal_5m_s3.zip", f"{a}seeds/deploy_armfilter_5m_s3.zip"]
    steps.append(_deploy(pair, "results/studies/deploy_armfilter_5m/pilot",
                         ("none", "delay1", "delay3", "camera3", "noise1", "targetnoise1",
                          "noise2")))
    # smoothness as a policy regulariser (CAPS) instead of the reward term and the low-pass,
    # and its control without either (pilots, training seed 3), against deploy_nominal
    # and CAPS with the filter on the tip's readings too
    steps += [_report("deploy_caps_5m"), _report("deploy_unsmoothed_5m"),
              _report("deploy_caps_armfilter_5m"),
              _compare("deploy_caps_5m", "deploy_nominal_5m"),
              _compare("deploy_unsmoothed_5m", "deploy_nominal_5m"),
              _compare("deploy_caps_5m", "deploy_unsmoothed_5m"),
              _compare("deploy_caps_armfilter_5m", "deploy_caps_5m")]
    caps = [f"{a}seeds/{s}_5m_s3.zip" for s in ("deploy_nominal", "deploy_unsmoothed",
                                                 "deploy_caps", "deploy_caps_armfilter")]
    steps.append(_deploy(caps, "results/studies/deploy_caps_5m/pilot"))
    # CAPS with the tip filter grown to five seeds: against deploy_nominal's five (paired by
    # training seed) and every seed's deployability rows (issue 36's targets, per seed)
    steps.append(_compare("deploy_caps_armfilter_5m", "deploy_nominal_5m"))
    caps5 = [f"{a}seeds/deploy_caps_armfilter_5m_s{k}.zip" for k in range(1, 6)]
    steps.append(_deploy(caps5, "results/studies/deploy_caps_armfilter_5m"))
    # where the deployment world's precision goes (device pilots, seed 3, the gpu profile):
    # nominal episodes alone against the headline's preset, then 3 in 4 and 1 in 2 nominal,
    # then the same preset under the cpu profile; and their deployability rows
    share = "results/studies/deploy_caps_armfilter_5m/nominal_share_gpu"
    steps += [_pair(a, b, f"{share}/{b}_vs_{a}.md") for a, b in pairwise(SHARE_LADDER)]
    gpu3 = [f"{a}seeds/{m}.zip" for m in SHARE_LADDER[1:4]]
    steps.append(_deploy(gpu3, share))
    # issue 36's candidate from those pilots, five seeds: against deploy_caps_armfilter's five
    # (paired by training seed) and every seed's deployability rows
    steps += _five_seeds("deploy_large_batch_5m", "deploy_caps_armfilter_5m")
    # ... with nine nominal episodes in ten: the precision it buys, the latency it costs
    steps += _five_seeds("deploy_large_batch_n90_5m", "deploy_large_batch_5m")
    # ... with 256x256 networks (seeds 1 and 3 trained here, 2, 4 and 5 on the lent H200 with
    # the same PPO sizes: the preset's own are the gpu profile's)
    steps += _five_seeds("deploy_large_batch_wide_5m", "deploy_large_batch_5m")
    # the recommended model for hardware against the previous candidate on all 1,000 test
    # seeds: the targets' margins (2.0 cm at 1 and 3 steps, acceptance) with CIs a third as wide
    chosen = [f"{a}deploy_large_batch_wide_5m.zip", f"{a}deploy_large_batch_5m.zip"]
    steps.append(_deploy(chosen, "results/studies/deploy_large_batch_wide_5m/test1000",
                         seeds="0-999"))
    # ... the wide networks with nine nominal episodes in ten: the share's precision on top
    steps += _five_seeds("deploy_large_batch_wide_n90_5m", "deploy_large_batch_wide_5m")
    # ... with CAPS's spatial weight tripled (five seeds here; the H200's first tries of seeds
    # 1, 2 and 4 were cut at 4.5M steps, their curves in results/bench/device_2026-11-27b/)
    steps += _five_seeds("deploy_large_batch_caps30_5m", "deploy_large_batch_5m")
    # ... started from the headline study's trained seeds (precision first, then the
    # deployment world; 5M steps on top of theirs): against the same preset from random weights,
    # and against the wide candidate
    steps += _five_seeds("deploy_large_batch_from_headline_5m", "deploy_large_batch_5m")
    steps.append(_compare("deploy_large_batch_from_headline_5m", "deploy_large_batch_wide_5m"))
    steps.append(Step(("results/studies/deploy_large_batch_from_headline_5m/curve.md",
                       "results/studies/deploy_large_batch_from_headline_5m/curve.png"),
                      ("studies/runs.py", "curve", "--studies",
                       "deploy_large_batch_from_headline_5m", "deploy_large_batch_5m", "--plot",
                       "{out1}"), _runs("deploy_large_batch_from_headline_5m",
                                        "deploy_large_batch_5m"), stdout=True))
    # ... its control: deploy_large_batch's own seeds trained on for 5M steps more (10M in all)
    cont = "deploy_large_batch_continued_5m"
    steps += _five_seeds(cont, "deploy_large_batch_5m")
    steps += [_compare(cont, "deploy_large_batch_from_headline_5m"),
              _compare(cont, "deploy_large_batch_wide_5m")]
    # the new candidate for hardware against the previous one on all 1,000 test seeds
    chosen = [f"{a}deploy_large_batch_10m.zip", f"{a}deploy_large_batch_wide_5m.zip"]
    steps.append(_deploy(chosen, "results/studies/deploy_large_batch_continued_5m/test1000",
                         seeds="0-999"))
    # ... with the lead's low-pass under noise only (10 Hz, tuned on the tuning seeds: the same
    # weights, archived by eval.py --adopt): every row, the noise rows against the filtered
    # rival, and the five seeds' noise rows at the same cutoff
    lp = "results/studies/deploy_large_batch_continued_5m/lowpass"
    chosen = [f"{a}deploy_large_batch_10m_lp10.zip", f"{a}deploy_large_batch_10m.zip"]
    steps += [_deploy(chosen, f"{lp}1000", ("none", "delay1", "delay3", "camera1", "camera3",
                                            "noise1", "noise2"), "0-999"),
              _deploy(chosen, f"{lp}1000/vs_rival", ("noise1", "noise2"), "0-999"),
              _deploy(chosen, f"{lp}1000/target_noise", ("targetnoise1", "targetnoise2"),
                      "0-999"),
              _deploy([f"{a}seeds/{cont}_s{k}.zip" for k in range(1, 6)], lp,
                      ("noise1", "noise2"), "0-99", "--noisy-lead-filter-hz", "10"),
              # where its acceptance gap under latency lies: by when the arm's check starts
              _deploy(chosen[:1], f"{lp}1000/check_window", ("none", "delay1", "delay3"),
                      "0-999", "--check-from", "0.75", "1", "1.5", "2")]
    # ... with the Panda's joint acceleration limits in the reward (w_limit), against its
    # control: the same start, budget and world without the term
    steps += _five_seeds("deploy_large_batch_limit_continued_5m", cont)
    # ... exploring with gSDE instead of a fresh Gaussian each step (the same start and
    # budget), and with the limit term on what the lead adds (limit_lead_only) on top of it:
    # against each other, and all ten seeds' acceptance on the 1,000 test seeds (the two
    # studies paired: each the mean over its seeds)
    sde, light = ("deploy_large_batch_sde_continued_5m",
                  "deploy_large_batch_limit_lead_sde_light_continued_5m")
    steps += _five_seeds(sde, cont) + _five_seeds(light, sde)
    steps.append(_deploy_studies(sde, light, f"results/studies/{light}/test1000",
                                 ("none", "delay1", "delay3"), "0-999", "--check-from", "0.75"))
    # ... the curvature term on the policy's mean action (caps_curvature), from the same start
    # and budget: the pilots' weights on 500 selection seeds (training seed 2, the hardware
    # model's; never a test seed), then weight 10's five seeds against their control and all
    # ten seeds' acceptance on the 1,000 test seeds (the two studies paired)
    curv = "deploy_large_batch_curv10_continued_5m"
    pilots = [f"{a}seeds/{cont}_s2.zip", *(f"{a}seeds/deploy_large_batch_curv{w}_continued_5m_s2.zip"
                                           for w in (3, 10, 30, 100))]
    steps.append(_deploy(pilots, f"results/studies/{curv}/pilots_selection500",
                         ("none", "delay1", "delay3", "noise1"), "5000000-5000499"))
    # ... weight 10 without latency and 30 or 100 with it (caps_curvature_delayed): pilots,
    # training seed 2, beside weight 10 and 30 everywhere, on the same 500 selection seeds
    late = [f"{a}seeds/deploy_large_batch_curv{w}_continued_5m_s2.zip" for w in (10, 30)] + [
        f"{a}seeds/deploy_large_batch_curv10_late{w}_continued_5m_s2.zip" for w in (30, 100)]
    steps.append(_deploy(late, f"results/studies/{curv}/late_pilots_selection500",
                         ("none", "delay1", "delay3", "noise1"), "5000000-5000499"))
    steps += _study_against(curv, cont)
    # ... with the policy's own last actions observed, undelayed (recent_actions), from the
    # same start and budget: against curv10, and all ten seeds' acceptance on the test seeds
    act = "deploy_large_batch_curv10_actions_continued_5m"
    steps += _study_against(act, curv)
    # ... its chosen seed (the selection rule) with the same 10 Hz low-pass under noise, against
    # the hardware model: every row on all 1,000 test seeds
    steps.append(_every_row(act, "deploy_large_batch_curv10_actions_10m_lp10",
                            "deploy_large_batch_curv10_10m_lp10"))
    # ... with latency and noise drawn apart in training (split_conditions), from the same
    # start and budget: against curv10
    steps += _study_against("deploy_large_batch_curv10_split_continued_5m", curv)
    # ... the recent actions with the last 4 observations stacked, against the recent actions
    stack = "deploy_large_batch_curv10_actions_stack4_continued_5m"
    steps += _study_against(stack, act)
    # ... its chosen seed (the selection rule: seed 2) with the hardware model's 10 Hz low-pass
    # under noise, against the hardware model: every row on all 1,000 test seeds
    steps.append(_every_row(stack, "deploy_large_batch_curv10_actions_stack4_10m_lp10",
                            "deploy_large_batch_curv10_10m_lp10"))
    # ... with 8 observations stacked instead of 4, against the 4-stack
    steps += _study_against("deploy_large_batch_curv10_actions_stack8_continued_5m", stack)
    # ... the 4-stack's five seeds trained 5M steps more: against their starts; its chosen seed
    # (the selection rule) with the same 10 Hz low-pass under noise beside the 4-stack's, every
    # row on all 1,000 test seeds; and its pilots (seeds 2 and 4, the first trained) beside
    # their starts on 500 selection seeds
    again = "deploy_large_batch_curv10_actions_stack4_continued_again_5m"
    steps += _study_against(again, stack)
    steps.append(_every_row(again, "deploy_large_batch_curv10_actions_stack4_15m_lp10",
                            "deploy_large_batch_curv10_actions_stack4_10m_lp10"))
    steps.append(_deploy([f"{a}seeds/{name}_s{k}.zip" for k in (2, 4) for name in (stack, again)],
                         f"results/studies/{again}/pilots_selection500",
                         ("none", "delay1", "delay3", "noise1"), "5000000-5000499"))
    # ... and those 15M seeds trained 5M steps more, gently (their own exploration, lr 3e-4):
    # against their starts; its chosen seed with the same 10 Hz low-pass under noise beside the
    # 15M hardware model, every row on all 1,000 test seeds
    fine = "deploy_large_batch_curv10_actions_stack4_finetuned_5m"
    steps += _study_against(fine, again)
    steps.append(_every_row(fine, "deploy_large_batch_curv10_actions_stack4_20m_lp10",
                            "deploy_large_batch_curv10_actions_stack4_15m_lp10"))
    # ... and the same gentle fine-tune with half the episodes nominal: against the gentle
    # one (and its starts' precision); its chosen seed with the 10 Hz low-pass beside the
    # hardware model, every row
    n50 = "deploy_large_batch_curv10_actions_stack4_finetuned_n50_5m"
    steps += _study_against(n50, fine) + [_compare(n50, again)]
    steps.append(_every_row(n50, "deploy_large_batch_curv10_actions_stack4_20m_n50_lp10",
                            "deploy_large_batch_curv10_actions_stack4_15m_lp10"))
    # ... and the gentle fine-tune with curvature weight 100 where there is latency: its
    # precision against the gentle one and its starts; both studies' ten seeds at 30 ms of
    # latency, the row its chosen seed was adopted for, and (run after the adoption) without
    # latency and at 10 ms; its chosen seed every row beside the hardware model it replaced
    late = "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m"
    steps += [_report(late), _compare(late, fine), _compare(late, again),
              _deploy_studies(fine, late, f"results/studies/{late}/test1000_delay3",
                              ("delay3",), "0-999", "--check-from", "0.75"),
              _deploy_studies(fine, late, f"results/studies/{late}/test1000_none_delay1",
                              ("none", "delay1"), "0-999", "--check-from", "0.75"),
              _every_row(late, HARDWARE, "deploy_large_batch_curv10_actions_stack4_15m_lp10"),
              # the hardware model's share of the gain its own oracle shows (issue 37's measure)
              _with_oracle(late, HARDWARE, "ilc_hardware")]
    # ... and the same fine-tune trained with the planner's hand in the loop: its spread (its
    # summaries' test seeds played with the hand, as it was trained); the like-for-like tables
    # (both studies with the hand) are results_online.py's
    steps.append(_report(LATE100_HAND))
    # is the ceiling's lead one function of the trajectory? three oracles started from three
    # leads (the headline, the gentle preview lead, the hardware model), test seeds 0-199
    oracles = ("ilc", "ilc_preview_finetuned", "ilc_hardware")
    steps.append(Step(("results/studies/ilc/agreement.md",),
                      ("studies/bias.py", "--prefixes", *oracles, "--agreement"),
                      tuple(f"rollouts/{o}" for o in oracles), stdout=True, section="all"))
    # ... its chosen seed (the selection rule), with the hardware model's 10 Hz low-pass under
    # noise (eval.py --adopt, the cutoff not re-tuned), against the hardware model: every row
    # on all 1,000 test seeds, the noise rows against the filtered rival
    steps.append(_every_row(curv, "deploy_large_batch_curv10_10m_lp10",
                            "deploy_large_batch_10m_lp10"))
    # ... and its five seeds' noise rows at the same 10 Hz (not re-tuned per seed)
    steps.append(_deploy([f"{a}seeds/{curv}_s{k}.zip" for k in range(1, 6)],
                         f"results/studies/{curv}/lowpass", ("noise1", "noise2"), "0-99",
                         "--noisy-lead-filter-hz", "10"))
    # where the learned lead's jerk under noise comes from: the target's readings alone noisy
    split = [f"{a}seeds/deploy_nominal_5m_s3.zip", f"{a}seeds/deploy_nominal_5m_s1.zip",
             f"{a}seeds/deploy_kalman_5m_s2.zip"]
    steps.append(_deploy(split, "results/studies/deploy_nominal_5m/noise_split",
                         ("noise1", "targetnoise1", "noise2", "targetnoise2")))
    from results_online import online_steps  # (imports this module: called, not at the top)

    steps += online_steps()
    # issue 36's first table, with the headline of its day, and the hardware model beside them
    deploy_models = [f"{a}{PREVIOUS_HEADLINE}.zip", f"{a}delayed_5m.zip", f"{a}{S}.zip",
                     f"{a}{DEPLOY}.zip", f"{a}{HARDWARE}.zip"]
    steps.append(Step(("results/studies/deploy/deploy.md", "results/studies/deploy/deploy.png"),
                      ("studies/deploy.py", "--models", *deploy_models, "--seeds", "0-99",
                       "--out", "{dir}"), tuple(deploy_models), section="all"))
    return steps
