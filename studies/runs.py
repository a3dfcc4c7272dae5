"""Training runs as committed summaries, so every spread table and every archived seed can be
recomputed from git alone (run folders stay out of git: they are large and machine-local).

    uv run studies/runs.py summarize --study v5 --runs sweeps/v5/runs/*/  # -> results/runs/v5/
    uv run studies/runs.py baselines                                 # -> results/runs/baselines.json
    uv run studies/runs.py report --study v5                         # spread table (markdown)
    uv run studies/runs.py choose --study v5 [--archive-as indep_v5 --runs sweeps/v5/runs]
    uv run studies/runs.py keep --study delayed_5m --runs sweeps/delayed_5m/runs  # each seed
    uv run studies/runs.py compare --study v5_joint --against-study v5  # two studies, paired
    uv run studies/runs.py compare --study preview_5m --against-study baseline:feedforward
    uv run studies/runs.py rates --study v5          # the baselines at 100 Hz and 500 Hz
    uv run studies/runs.py rank                      # studies by evaluation-set error (old rule)
    uv run studies/runs.py curve --studies ikfree_long ikfree \
        --plot results/studies/ikfree_long/curve.png
    uv run studies/runs.py diagnostics --csv results/studies/ikfree_long/diagnostics.csv  # PPO's health

(studies/rederive.py retrains a summary's run for its first evaluations and compares the curve.)

A summary (results/runs/<study>/seed_<N>.json) holds the run's full training config, code
commit and CPU (runs trained after 2026-11-25), timesteps and wall time, its evaluation curve
(evaluation-set error every eval_freq steps), its best evaluation, the SHA-256 of its best
model, and that model's per-trajectory test metrics on the 1,000 test seeds (mean error,
settled error, jerk). The baselines file holds the same per-trajectory metrics of the classical
controller and the analytic lead, at 100 Hz and with the IK at 500 Hz. `report` and `choose`
read only these files. `keep` commits every seed's best model (archive/seeds/<study>_s<N>.zip
and its sidecar), for the tables that evaluate each seed and not only the chosen one.

The choice rule (`choose`): the run with the lowest best evaluation-set error (never a test
seed); a tie (equal to 0.01 cm, the printed precision) goes to the lower training seed.
The evaluation-set order (`rank`), the headline rule until 2026-11-26: among studies of at
least 3 seeds, the one whose seeds' best evaluation-set errors have the lowest mean (one lucky
seed on 15 evaluation trajectories does not make a configuration better), and its chosen run.
Since 2026-11-26 the headline is chosen by the selection rule instead (`studies/selection.py
rank`, results/studies/rank/rank.md): 15 trajectories could not separate the studies.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from panda_lead.config import knows_path
from panda_lead.errors import (
    UserError,
    check_output,
    check_plain_name,
    did_you_mean,
    exit_on_user_error,
    parse_cli,
    printable,
)
from panda_lead.summaries import check_test_lists, read_json, read_summary

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_logs import (  # noqa: E402, F401  (studies/run_logs.py: a run's log and curves;
    DIAGNOSTICS,  # DIAGNOSTICS and first_below are this module's too, as tests and docs read it)
    diagnostics,
    first_below,
    stopped_curve,
    time_to_quality,
)

RUNS_DIR = Path("results/runs")
TEST = "0-999"
KEYS = ("mean_err", "settled_err", "jerk_rms")


@dataclass
class Args:
    command: tyro.conf.Positional[Literal["summarize", "baselines", "report", "choose",
                                          "compare", "rates", "rank", "curve",
                                          "diagnostics", "keep"]]
    """What to do (see above)."""
    runs: list[Path] = field(default_factory=list)
    """summarize: run folders (each with best_model.zip, config.json, tb/progress.csv);
    choose --archive-as and keep: the folders holding the study's run folders."""
    study: str = "v5"
    """The study's name: its summaries live in results/runs/<study>/."""
    against: str = "analytic"
    """report: the baseline each run is compared with (classical, analytic, classical_500hz,
    analytic_500hz)."""
    against_study: str | None = None
    """compare: the study --study is compared with (differences are study - against-study); either
    side may be baseline:<name>, a controller of baselines.json (e.g. baseline:feedforward)."""
    archive_as: str | None = None
    """choose: archive the chosen run's best model under this name (needs its run folder)."""
    by: Literal["evaluation", "selection"] = "evaluation"
    """choose and report: the rule that chooses a study's run. evaluation: the lowest best
    error on the 15 evaluation trajectories (every study's archive so far); selection: issue
    37's rule on the selection set (every seed scored, `studies/selection.py score`; lowest
    mean error, the smoother of tied neighbours first), the rule the README states for the
    headline."""
    force: bool = False
    """Replace existing summaries, baselines or an archived name."""
    bootstrap: int = 10000
    """Bootstrap resamples for the CIs."""
    studies: list[str] = field(default_factory=list)
    """curve: the studies whose evaluation curves are drawn (every seed of each)."""
    plot: Path | None = None
    """curve: the figure's path (PNG)."""
    stopped: list[Path] = field(default_factory=list)
    """curve: diagnostics files (`diagnostics --csv`) of runs stopped before their end, which
    have no summary: their evaluation rows are drawn dashed, so a run that came apart stays
    in the figure."""
    csv: Path | None = None
    """diagnostics: the run's diagnostics file (written from --runs RUN when given, else read)."""
    margin_cm: float = 1.5
    """curve: the quality bar for the steps-to-quality table is the classical evaluation error
    less this (studies/ttq.py's bar)."""
    window: int = 2_000_000
    """diagnostics: training steps per row of the table."""
    by_shape: bool = False
    """compare: also the differences within each target shape (circle, fig8, fly), each shape
    its own family for the findings rule."""


def _metrics_on_test(ctrl) -> dict[str, list[float]]:
    from panda_lead.metrics import rollout_metrics
    from panda_lead.metrics.pairing import charged
    from panda_lead.rollout import iter_record
    from panda_lead.seeds import parse_seed_range

    seeds = parse_seed_range(TEST)
    out: dict[str, list[float]] = {k: [] for k in KEYS}
    for r in iter_record(ctrl.config, ctrl.act, seeds, meta=ctrl.meta):
        m = rollout_metrics(charged(r)[0])  # a failure is charged, as in every table
        for k in KEYS:
            out[k].append(round(float(m[k]), 5))
    return out


def _run_best(run: Path, side: dict) -> dict:
    """The run's best evaluation, from the best model's own sidecar (bound to the model by its
    hash), as best.json holds it; best.json is read only for a model saved without it."""
    from panda_lead.summaries import CHECKS

    metrics = side.get("eval_metrics")
    if isinstance(metrics, dict):
        best, source = {"timesteps": side.get("timesteps"), **metrics}, run / "best_model.json"
    else:
        source = run / "best.json"
        best = read_json(source, "a run's best.json", limit=1 << 20)
    CHECKS["best"]({"best": best}, source)
    return best


def _run_curve(run: Path) -> list[list[float]]:
    """The run's evaluation curve (tb/progress.csv), its damage as one line."""
    from panda_lead.training.evaluation import eval_curve

    try:
        curve = eval_curve(run)
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, OverflowError) as exc:
        raise UserError(f"{run / 'tb' / 'progress.csv'}: not a readable training log "
                        f"({printable(exc, 120)})") from None
    if any(not all(map(np.isfinite, point)) for point in curve):
        raise UserError(f"{run / 'tb' / 'progress.csv'}: an evaluation row is not finite")
    return curve


def summarize(args: Args) -> None:
    from panda_lead import harness
    from panda_lead.atomicio import atomic_write, folder_lock
    from panda_lead.models import upgrade_legacy, verify

    if not args.runs:
        raise UserError("summarize needs run folders: --runs sweeps/NAME/runs/*/")
    out_dir = RUNS_DIR / check_plain_name(args.study, "--study")
    todo = []  # every run checked before the first is evaluated (each takes minutes)
    for run in map(Path, args.runs):
        best, final = run / "best_model.zip", run / "final_model.zip"
        if not best.is_file() or not final.is_file():
            raise UserError(f"{run}: not a finished run folder (no best_model.zip/final_model.zip)")
        for model in (best, final):
            upgrade_legacy(model)  # runs saved before models carried their sidecar
        side, last = verify(best), verify(final)
        config = side["train_config"]
        path = out_dir / f"seed_{config['seed']}.json"
        if any(path == p for *_, p in todo):
            raise UserError(f"two of --runs are training seed {config['seed']}")
        todo.append((run, side, last, _run_best(run, side), _run_curve(run), path))
    with folder_lock(out_dir, f"the study {args.study}'s summaries"):
        for run, side, last, best, curve, path in todo:
            if path.exists() and not args.force:
                print(f"{path} exists (add --force to redo it)")
                continue
            config = side["train_config"]
            ctrl = harness.build("policy", 500, run / "best_model.zip")
            summary = {"study": args.study, "run": run.name, "preset": config.get("preset"),
                       "seed": config["seed"], "train_config": config,
                       "commit": side.get("commit"), "cpu": side.get("cpu"),
                       "timesteps": last["timesteps"], "wall_time_s": last.get("wall_time_s"),
                       "eval_curve": curve, "best": best,
                       "best_model_sha256": side["model_sha256"], "test_seeds": TEST,
                       "test": _metrics_on_test(ctrl)}
            if side.get("init_from"):  # a warm-started run: its steps are on top of this model's
                summary["init_from"] = side["init_from"]
            with atomic_write(path, ".tmp.json") as tmp:
                Path(tmp).write_text(json.dumps(summary, indent=1) + "\n")
            print(f"wrote {path}: test mean error {np.mean(summary['test']['mean_err']):.3f} cm")


BASELINES = {"classical": ("classical", {}), "analytic": ("analytic", {}),
             "classical_500hz": ("classical", {"ik": {"substep_ik": True}}),
             "analytic_500hz": ("analytic", {"ik": {"substep_ik": True}}),
             # the classical rivals that KNOW THE PLANNED PATH (issue 37; tuned on the tuning
             # seeds, results/studies/preview/rivals_tuning.md): never beside causal rows
             "future_target": ("future_target", {}), "feedforward": ("feedforward", {}),
             "feedforward_plan": ("feedforward_plan", {})}
KNOWS_PATH = ("future_target", "feedforward", "feedforward_plan")


def baselines(args: Args) -> None:
    """Every baseline's per-trajectory test metrics into baselines.json: the ones the file
    lacks (a rival added later costs only itself), all of them with --force."""
    from panda_lead import harness
    from panda_lead.atomicio import atomic_write

    path = RUNS_DIR / "baselines.json"
    out = {} if args.force or not path.exists() else read_json(path, "the baselines file")
    if out and out.get("test_seeds") != TEST:
        raise UserError(f"{path} is for test seeds {out.get('test_seeds')}, not {TEST}; add "
                        "--force to recompute it")
    missing = [name for name in BASELINES if name not in out]
    if not missing:
        raise UserError(f"{path} has every baseline; add --force to recompute it")
    tau_500 = _tau_500hz()
    out = {**out, "test_seeds": TEST, "analytic_500hz_tau": tau_500}
    for name in missing:
        kind, settings = BASELINES[name]
        tau = tau_500 if name == "analytic_500hz" else None
        out[name] = _metrics_on_test(harness.build(kind, 500, None, settings, tau=tau))
        print(f"{name}: test mean error {np.mean(out[name]['mean_err']):.3f} cm", flush=True)
    with atomic_write(path, ".tmp.json") as tmp:
        Path(tmp).write_text(json.dumps(out, indent=1) + "\n")


def _tau_500hz() -> float:
    """The analytic lead's tau with the IK at 500 Hz, as tuned on the tuning seeds
    (`uv run studies/tau.py --env.ik.substep-ik True`, results/studies/tau/tau_500hz.txt)."""
    path = Path("results/studies/tau/tau_500hz.txt")
    try:
        with open(path, encoding="utf-8") as f:
            tau = float(f.read(1 << 16).split("best tau")[1].split()[0])
    except (OSError, UnicodeDecodeError, IndexError, ValueError) as exc:
        raise UserError(f"{path}: no 'best tau' number ({printable(exc, 120)}); run "
                        "studies/tau.py as its docstring says") from None
    if not 0 <= tau <= 1:
        raise UserError(f"{path}: best tau {tau} is not a number of seconds in [0, 1]")
    return tau


def load_study(study: str, needs=("best", "test")) -> list[dict]:
    """A study's summaries, each read with the size bound and checked for the fields ``needs``
    (panda_lead.summaries.CHECKS) before any work: a damaged one is one line naming it."""
    files = sorted((RUNS_DIR / check_plain_name(study, "--study")).glob("seed_*.json"))
    if not files:
        raise UserError(f"no summaries under {RUNS_DIR / study}/ (run `summarize` first)")
    runs = sorted((read_summary(f, needs) for f in files), key=lambda s: s["seed"])
    if "test" in needs:
        same_test_seeds(runs, f"{RUNS_DIR / study}/")
    return runs


def same_test_seeds(runs: list[dict], where: str, baseline: dict | None = None) -> None:
    """Paired by test trajectory only if every summary (and the baseline) names one seed set."""
    named = {s.get("test_seeds", TEST) for s in runs}
    if baseline is not None:
        named.add(baseline["test_seeds"])
    if len(named) > 1:
        raise UserError(f"{where}: the summaries (and baselines) name different test seeds "
                        f"({', '.join(sorted(map(str, named)))}): not paired by trajectory")


def load_baseline(name: str) -> dict:
    """One baseline's per-trajectory lists from baselines.json (bounded, checked), with the
    file's test_seeds."""
    path = RUNS_DIR / "baselines.json"
    if not path.is_file():
        raise UserError(f"no {path} (run `uv run studies/runs.py baselines` first)")
    base = read_json(path, "the baselines file")
    if not isinstance(base, dict) or name not in base or not isinstance(base[name], dict):
        raise UserError(f"no baseline {name!r} in {path}")
    check_test_lists(base[name], path, base.get("test_seeds"), name)
    return {**base[name], "test_seeds": base["test_seeds"]}


def compare_studies(args: Args) -> None:
    """Two configurations, each over its training seeds, paired by test trajectory; the CI is
    metrics.two_level_bootstrap's (training seeds and trajectories resampled)."""
    if not args.against_study:
        raise UserError("compare needs --against-study NAME")
    a, b = _study_or_baseline(args.against_study), _study_or_baseline(args.study)
    same_test_seeds(a + b, f"--study {args.study} against --against-study {args.against_study}")
    from panda_lead.metrics import bootstrap_verdicts, two_level_bootstrap

    rng = np.random.default_rng(0)
    metrics = {key: (name, np.array([s["test"][key] for s in a]),  # (seeds, trajectories)
                     np.array([s["test"][key] for s in b]))
               for key, name in (("mean_err", "mean error"), ("settled_err", "settled error"),
                                 ("jerk_rms", "jerk RMS"))}

    def rows(keep: np.ndarray | slice, label: str = "") -> list[str]:
        """One row per metric over the trajectories ``keep`` selects."""
        lines, cis, resamples = [], [], []
        for name, ma, mb in metrics.values():
            ma, mb = ma[:, keep], mb[:, keep]
            d = mb.mean(axis=0) - ma.mean(axis=0)
            (lo, hi), boots = two_level_bootstrap(ma, mb, args.bootstrap, rng)
            cis.append((lo, hi))
            resamples.append(boots)
            lines.append(f"| {label}{name} | {ma.mean():.3f} | {mb.mean():.3f} | "
                         f"{d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}] {{verdict}} | "
                         f"{np.median(d):+.3f} | {100 * np.mean(d < 0):.0f}% |")
        # The findings rule (metrics.finding_verdict): CI, pairs and Holm p over these metrics.
        verdicts = bootstrap_verdicts(cis, resamples, d.size)
        return [line.format(verdict=v) for line, v in zip(lines, verdicts, strict=True)]

    lines = rows(slice(None))
    if args.by_shape:
        from panda_lead.seeds import parse_seed_range
        from panda_lead.trajectory import sample

        shapes = np.array([sample(int(t)).shape
                           for t in parse_seed_range(a[0]["test_seeds"])])
        for shape in sorted(set(shapes)):
            lines += rows(shapes == shape, f"{shape} (n={int(np.sum(shapes == shape))}): ")
    against = _described(args.against_study, a)
    print(f"{_described(args.study, b)} minus {against}, "
          f"each the mean over its seeds per test trajectory ({TEST}); 95% CI: two-level "
          f"bootstrap over training seeds and trajectories ({args.bootstrap} resamples). "
          f"`uv run studies/runs.py compare --study {args.study} --against-study "
          f"{args.against_study}{' --by-shape' if args.by_shape else ''}`"
          + (" Per target shape, each shape's rows their own family." if args.by_shape else "")
          + "\n")
    print(f"| metric | {args.against_study} | {args.study} | mean diff [95% CI] | median diff "
          f"| {args.study} better on |")
    print("|---|---|---|---|---|---|")
    print("\n".join(lines))


def _described(name: str, runs: list[dict]) -> str:
    """A compared side as the table's first line names it."""
    if name.startswith("baseline:"):
        rival = name.removeprefix("baseline:")
        return (f"`{name}` (a classical controller, no training seeds"
                + (", KNOWS THE PLANNED PATH)" if rival in KNOWS_PATH else ")"))
    return f"`{name}` ({len(runs)} seeds: {', '.join(str(s['seed']) for s in runs)})"


def _study_or_baseline(name: str) -> list[dict]:
    """A study's summaries, or for ``baseline:<name>`` a baseline of baselines.json as a study
    of one seed (a classical controller has no training seeds: the bootstrap then resamples
    the trajectories alone on its side)."""
    if not name.startswith("baseline:"):
        return load_study(name, ("test",))
    base = name.removeprefix("baseline:")
    if base not in BASELINES:
        raise UserError(f"unknown baseline {base!r}; choose from {', '.join(BASELINES)}"
                        + did_you_mean(base, BASELINES))
    test = load_baseline(base)
    return [{"seed": "-", "test": test, "test_seeds": test["test_seeds"]}]


def rates(args: Args) -> None:
    """Apples to apples: the classical controller and the analytic lead with the IK at 100 Hz
    (every control step, as the learned lead) and at 500 Hz (every physics substep, as the
    reference work's IK+PD), each paired with the other rate and with the study's chosen
    learned lead (100 Hz), per test trajectory."""
    from panda_lead.metrics import deltas_diffs

    base = {k: load_baseline(k) for k in ("classical", "classical_500hz", "analytic",
                                          "analytic_500hz")}
    tau = read_json(RUNS_DIR / "baselines.json", "the baselines file").get("analytic_500hz_tau")
    runs = load_study(args.study)
    same_test_seeds(runs, f"{RUNS_DIR / args.study}/", base["classical"])
    learned = choose_run(runs)
    print(f"Baselines with the IK at 100 Hz and at 500 Hz (analytic lead's tau re-tuned at 500 Hz "
          f"on the tuning seeds: {tau} s) against the learned lead (`{args.study}` seed "
          f"{learned['seed']}, IK at 100 Hz), test seeds {TEST} (n=1000), paired by trajectory, "
          "95% bootstrap CIs. `uv run studies/runs.py rates`\n")
    print("| controller | mean (cm) | settled (cm) | minus the same at 100 Hz | learned lead "
          "minus it | learned better on |")
    print("|---|---|---|---|---|---|")
    mine = np.array(learned["test"]["mean_err"])
    for name in base:
        m = np.array(base[name]["mean_err"])
        settled = np.mean(base[name]["settled_err"])
        if name.endswith("_500hz"):
            d = m - np.array(base[name.removesuffix("_500hz")]["mean_err"])
            vs100, = deltas_diffs([(d, "mean")], args.bootstrap)
        else:
            vs100 = ""
        dl = mine - m
        print(f"| {name} | {m.mean():.2f} | {settled:.2f} | {vs100} | "
              f"{deltas_diffs([(dl, 'mean')], args.bootstrap)[0]} | "
              f"{100 * np.mean(dl < 0):.0f}% |")


def choose_run(runs: list[dict]) -> dict:
    """The stated rule: lowest best evaluation error (to 0.01 cm), ties to the lower seed.
    A non-finite error never ranks or chooses (load_study refuses it; this is the last guard)."""
    bad = [s["seed"] for s in runs if not np.isfinite(s["best"]["mean_error_cm"])]
    if bad:
        raise UserError(f"seed(s) {bad}: best evaluation error is not a finite number")
    return min(runs, key=lambda s: (round(s["best"]["mean_error_cm"], 2), s["seed"]))


def report(args: Args) -> None:
    from panda_lead.metrics import deltas_diffs

    runs = load_study(args.study, ("best", "test", "model"))
    base = load_baseline(args.against)
    same_test_seeds(runs, f"{RUNS_DIR / args.study}/", base)
    chosen = chosen_by(args, runs)
    print(f"Study `{args.study}`: {len(runs)} training seeds, each its best evaluation-set model "
          f"on test seeds {TEST} (n=1000), 5 s episodes; differences are run - {args.against}, "
          "paired by trajectory, 95% bootstrap CIs; failed episodes charged. From "
          f"results/runs/{args.study}/ (`uv run studies/runs.py report --study {args.study}`).\n")
    print(f"| seed | steps | best eval (cm) | test mean (cm) | settled (cm) | mean diff vs "
          f"{args.against} | median diff | settled diff | better on |")
    print("|---|---|---|---|---|---|---|---|---|")
    means, settled = [], []
    for s in runs:
        mine, theirs = (np.array(x["mean_err"]) for x in (s["test"], base))
        d = mine - theirs
        ds = np.array(s["test"]["settled_err"]) - np.array(base["settled_err"])
        means.append(mine.mean())
        settled.append(np.mean(s["test"]["settled_err"]))
        mark = " (chosen)" if s is chosen else ""
        diffs = deltas_diffs([(d, "mean"), (d, "median"), (ds, "mean")], args.bootstrap)
        print(f"| {s['seed']}{mark} | {s['timesteps']:,} | {s['best']['mean_error_cm']:.2f} | "
              f"{mine.mean():.2f} | {settled[-1]:.2f} | {' | '.join(diffs)} | "
              f"{100 * np.mean(d < 0):.0f}% |")
    if len(runs) > 1:
        print(f"\nAcross the {len(runs)} seeds: test mean error {np.mean(means):.2f} ± "
              f"{np.std(means, ddof=1):.2f} cm (mean ± std; range {min(means):.2f}-"
              f"{max(means):.2f}), settled {np.mean(settled):.2f} ± {np.std(settled, ddof=1):.2f}.")
    print(f"Chosen by the rule ({RULES[args.by]}): seed "
          f"{chosen['seed']} (best model sha256 {chosen['best_model_sha256'][:12]}).")


def choose_by_selection(study: str, runs: list[dict], scores: Path) -> dict:
    """The seed issue 37's rule ranks first on the selection set: each seed's kept model
    (archive/seeds/<study>_s<k>) scored in ``scores``, the score of the model kept now."""
    found, missing = {}, []
    for s in runs:
        name = f"{study}_s{s['seed']}"
        side, score = Path("archive/seeds") / f"{name}.json", scores / f"{name}.json"
        if not (side.is_file() and score.is_file()):
            missing.append(name)
            continue
        rec = read_json(score, "a selection-set score")
        if rec.get("model_sha256") != read_json(side, "a kept model's sidecar").get("model_sha256"):
            raise UserError(f"{score} scored another model than archive/seeds/{name}.zip: "
                            "score it again (studies/selection.py score --force)")
        found[name] = (s, rec)
    if missing:
        raise UserError(f"--by selection needs every seed kept and scored; not: "
                        f"{', '.join(missing)} (studies/runs.py keep, then studies/selection.py "
                        "score --models archive/seeds/<name>.zip)")
    order = tie_ranked({k: np.asarray(r["mean_err_cm"]) for k, (_, r) in found.items()},
                       {k: float(np.mean(r["jerk_rms"])) for k, (_, r) in found.items()})
    return found[order[0][0]][0]


SELECTION_SCORES = Path("results/studies/rank/scores")  # studies/selection.py's SCORES
RULES = {"evaluation": "lowest best evaluation error, ties to the lower seed",
         "selection": "issue 37's, first on the selection set, the smoother of tied seeds first"}


def chosen_by(args: Args, runs: list[dict]) -> dict:
    """The study's chosen run by --by's rule (report marks it, choose archives it)."""
    if args.by == "selection":
        return choose_by_selection(args.study, runs, SELECTION_SCORES)
    return choose_run(runs)


def choose(args: Args) -> None:
    runs = load_study(args.study, ("best", "model") if args.archive_as else ("best",))
    chosen = chosen_by(args, runs)
    print(f"{args.study}: seed {chosen['seed']} (run {printable(chosen.get('run'))}, best "
          f"evaluation error {chosen['best']['mean_error_cm']:.3f} cm at "
          f"{chosen['best']['timesteps']:,} steps), by the rule: {RULES[args.by]}")
    if args.archive_as:
        from panda_lead.training.archive import archive_model, check_archive_free

        if not args.runs:
            raise UserError("--archive-as needs --runs FOLDER..., the folders holding the run "
                            "folders")
        check_archive_free(args.archive_as, args.force)  # before the run's quick test
        model = _bound_best_model(chosen, args)
        path = archive_model(model.parent, args.archive_as, force=args.force)
        print(f"archived {path}")


def _bound_best_model(s: dict, args: Args) -> Path:
    """The best model of summary ``s``'s run: its folder, a plain name (the summary checked it),
    looked for inside each of --runs, and the model there must be the one the summary measured
    (its SHA-256), or nothing is archived or kept."""
    from panda_lead.models import verify

    found = [Path(d) / s["run"] / "best_model.zip" for d in args.runs]
    found = [f for f in found if f.is_file()]
    if not found:
        raise UserError(f"run {s['run']} is in none of {[str(d) for d in args.runs]}: "
                        "use the machine that trained it")
    if verify(found[0])["model_sha256"] != s["best_model_sha256"]:
        raise UserError(f"{found[0]} is not the model results/runs/{args.study}/seed_{s['seed']}"
                        ".json summarizes (its SHA-256 differs): summarize again")
    return found[0]


SEEDS_DIR = Path("archive/seeds")


def seed_path(study: str, seed: int) -> Path:
    """Where `keep` archives a study's seed: archive/seeds/<study>_s<seed>.zip."""
    return SEEDS_DIR / f"{study}_s{seed}.zip"


def seed_models(study: str) -> dict[int, Path]:
    """A study's kept seeds' models, by training seed (seed_path's files that exist)."""
    import re

    pattern = re.compile(re.escape(study) + r"_s(\d+)\.zip")
    return {int(m.group(1)): p for p in SEEDS_DIR.glob(f"{study}_s*.zip")
            if (m := pattern.fullmatch(p.name))}


def _kept_from(side: dict, summary: dict) -> bool:
    """Whether a kept seed's sidecar names the run model ``summary`` measured: its source's
    SHA-256 (kept since 2026-11-28), or for older keeps its source run folder's name (unique
    per run: trial, seed and start time)."""
    if "source_sha256" in side:
        return side["source_sha256"] == summary["best_model_sha256"]
    same_seed = (side.get("study"), side.get("seed")) == (summary.get("study"), summary["seed"])
    return same_seed and Path(str(side.get("source", ""))).parent.name == summary["run"]


def keep(args: Args) -> None:
    """Every seed's best model of a study into archive/seeds/<study>_s<N>.zip (weights and
    sidecar, no card: these are evaluated in tables, the chosen run is the one to use). Each
    must be the model its committed summary was computed from (same SHA-256). A seed already
    kept as that model needs no run folder: a study grown on another machine or under another
    sweep name keeps its new seeds from the folders at hand."""
    from panda_lead.models import archive_lock, copy_with_sidecar, pair_state, verify

    if not args.runs:
        raise UserError("keep needs --runs FOLDER..., the folders holding the study's run folders")
    for s in load_study(args.study, ("model",)):
        dst = seed_path(args.study, s["seed"])
        if not args.force and pair_state(dst) == "valid" and _kept_from(verify(dst), s):
            print(f"{dst} exists (the model its summary measured; add --force to replace it)")
            continue
        src = _bound_best_model(s, args)
        dst.parent.mkdir(parents=True, exist_ok=True)
        with archive_lock(dst):
            if pair_state(dst) != "absent" and not args.force:
                print(f"{dst} exists (add --force to replace it)")
                continue
            copy_with_sidecar(src, dst, {"name": dst.stem, "source": str(src),
                                         "source_sha256": s["best_model_sha256"],
                                         "study": args.study, "seed": s["seed"]})
        print(f"kept {dst}")


def rank(args: Args) -> None:
    """Every study with committed summaries, ordered by the mean of its seeds' best
    evaluation-set errors (selection data only; test numbers are shown, never used)."""
    rows, preview = [], []
    for folder in sorted(p for p in RUNS_DIR.iterdir() if p.is_dir()):
        runs = load_study(folder.name)
        evals = [s["best"]["mean_error_cm"] for s in runs]
        row = (float(np.mean(evals)), folder.name, runs, evals)
        envs = (((s.get("train_config") or {}).get("env") or {}) for s in runs)
        (preview if any(knows_path(env) for env in envs) else rows).append(row)
    rows.sort(key=lambda r: r[0])
    preview.sort(key=lambda r: r[0])
    eligible = [r for r in rows if len(r[2]) >= 3]
    print("Studies by the mean of their seeds' best evaluation-set error (15 trajectories, "
          "never a test seed); **first** marks the first with >= 3 seeds, which was the "
          "headline until 2026-11-26. Since then the headline is chosen by the selection rule "
          "(`uv run studies/selection.py rank`, results/studies/rank/rank.md): this order is "
          "kept for the history it explains. Studies that know the planned path are ranked "
          "apart, after. `uv run studies/runs.py rank`\n")
    for title, group in (("", rows), ("\nKNOWS THE PLANNED PATH (never first)\n", preview)):
        if not group:
            continue
        print(title)
        print("| study | seeds | best eval per seed (cm) | mean | chosen seed | test mean (cm) | "
              "test settled (cm) |")
        print("|---|---|---|---|---|---|---|")
        for mean, name, runs, evals in group:
            c = choose_run(runs)
            mark = " **first**" if eligible and name == eligible[0][1] else ""
            print(f"| {name}{mark} | {len(runs)} | {', '.join(f'{e:.2f}' for e in evals)} | "
                  f"{mean:.2f} | {c['seed']} | {np.mean(c['test']['mean_err']):.2f} | "
                  f"{np.mean(c['test']['settled_err']):.2f} |")



# The selection rule that does not wobble (issue 37, stated 2026-11-26; docs/training.md):
# studies (or models) are ordered by their mean error on the selection set (seeds.SELECT_SEEDS,
# sized from the measured per-trajectory spread to separate 0.05 cm; every study under the
# same default evaluation env), and where two neighbours' paired 95% bootstrap CI of the
# difference includes 0, the smoother one (lower mean tip jerk) ranks first.
def tie_ranked(errors: dict[str, np.ndarray], jerks: dict[str, float], n_boot: int = 10000,
               seed: int = 0) -> list[tuple[str, bool]]:
    """Names in rank order by the rule above, each with whether it is tied (CI includes 0)
    with the one ranked just above it. ``errors``: per-trajectory mean error (cm) on the same
    trajectories, in the same order, for every name; ``jerks``: mean tip jerk per name. A swap
    only ever moves the smoother of two tied neighbours up, so the loop ends."""
    from panda_lead.metrics.stats import paired_ci

    def tied(a: str, b: str) -> bool:
        lo, hi = paired_ci(np.asarray(errors[b]) - np.asarray(errors[a]), n_boot, seed)
        return bool(lo <= 0.0 <= hi)

    order = sorted(errors, key=lambda k: (float(np.mean(errors[k])), k))
    changed = True
    while changed:
        changed = False
        for i in range(len(order) - 1):
            a, b = order[i], order[i + 1]
            if jerks[b] < jerks[a] and tied(a, b):
                order[i], order[i + 1] = b, a
                changed = True
    return [(name, i > 0 and tied(order[i - 1], name)) for i, name in enumerate(order)]


def curve(args: Args) -> None:
    """Evaluation-set error against training steps (log scale) for every seed of each study,
    from the committed summaries, with the classical and analytic references on the same
    evaluation set (recomputed here: 15 episodes each). --plot is never replaced without
    --force."""
    from panda_lead.outputs import claimed_outputs

    if not args.studies or args.plot is None:
        raise UserError("curve needs --studies NAME [NAME ...] and --plot FILE.png")
    check_output(args.plot, "--plot", args.force)
    studies = {name: load_study(name, ("curve",)) for name in args.studies}
    steps = {s["train_config"]["eval_steps"] for runs in studies.values() for s in runs}
    if len(steps) != 1:
        raise UserError(f"the studies were evaluated on episodes of different lengths: {steps}")
    (eval_steps,) = steps
    stopped = {str(p): stopped_curve(p) for p in args.stopped}  # a bad file fails before the work
    with claimed_outputs([args.plot], "--plot", args.force):
        _draw_curves(args, studies, stopped, eval_steps)


def _draw_curves(args: Args, studies: dict, stopped: dict, eval_steps: int) -> None:
    from panda_lead.config import EnvConfig
    from panda_lead.controllers import classical, make_analytic
    from panda_lead.metrics.figures import colours_for, pyplot, save_figure
    from panda_lead.training.evaluation import evaluate

    refs = {name: evaluate(ctrl, EnvConfig(), eval_steps)["mean_error_cm"]
            for name, ctrl in (("classical", classical), ("analytic lead", make_analytic()))}
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.8), constrained_layout=True)
    colours = colours_for([*studies, *map(str, args.stopped)])
    for name, runs in studies.items():
        for i, s in enumerate(runs):
            x, y = np.array(s["eval_curve"], dtype=float).T
            ax.plot(x, y, color=colours[name], lw=1, alpha=0.8,
                    label=f"{name} ({len(runs)} seed{'s' * (len(runs) > 1)})" if i == 0 else None)
    for path, (x, y) in stopped.items():
        ax.plot(x, y, color=colours[path], lw=1, ls="--",
                label=f"{Path(path).stem.removesuffix('_diagnostics')} (stopped at "
                      f"{x[-1] / 1e6:.1f}M)")
    for (name, cm), style in zip(refs.items(), ("--", ":"), strict=True):
        ax.axhline(cm, color="grey", ls=style, lw=1, label=f"{name} ({cm:.2f} cm)")
    ax.set(xscale="log", yscale="log", xlabel="training steps",
           ylabel="evaluation-set mean error (cm)",
           title="Evaluation curves (15 evaluation trajectories, never a test seed)")
    ticks = [t for t in (1, 1.5, 2, 3, 4, 6, 10, 20, 40) if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
    ax.set_yticks(ticks, [f"{t:g}" for t in ticks])
    ax.minorticks_off()  # the log axis's own minor labels (2 x 10^0 ...) would overprint them
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    print(f"wrote {save_figure(fig, args.plot)}", file=sys.stderr)  # stdout is the table
    for name, cm in refs.items():
        print(f"{name}: {cm:.2f} cm on the evaluation set")
    print(time_to_quality(studies, refs["classical"], args.margin_cm))


@exit_on_user_error
def main(args: Args) -> None:
    {"summarize": summarize, "baselines": baselines, "report": report, "choose": choose,
     "compare": compare_studies, "rates": rates, "rank": rank, "curve": curve,
     "diagnostics": diagnostics, "keep": keep}[args.command](args)


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
