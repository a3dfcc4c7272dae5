"""studies/runs.py: the rules that pick archived seeds and the headline from committed summaries."""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np
import pytest
from conftest import ROOT


@pytest.fixture
def runs(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("runs_study", ROOT / "studies" / "runs.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "RUNS_DIR", tmp_path)
    return module


def write_study(root, study, evals, test_err):
    (root / study).mkdir()
    for seed, e in evals.items():
        summary = {"seed": seed, "run": f"r{seed}", "best": {"mean_error_cm": e, "timesteps": 1},
                   "best_model_sha256": "0" * 64, "timesteps": 1, "test_seeds": "0-3",
                   "test": {"mean_err": [test_err] * 4, "settled_err": [test_err / 2] * 4,
                            "jerk_rms": [1.0] * 4}}
        (root / study / f"seed_{seed}.json").write_text(json.dumps(summary))


def test_a_tie_on_the_evaluation_set_goes_to_the_lower_seed(runs, tmp_path):
    write_study(tmp_path, "s", {3: 2.004, 1: 2.001, 2: 2.10}, 2.0)
    assert runs.choose_run(runs.load_study("s"))["seed"] == 1  # 2.00 == 2.00 to 0.01 cm
    write_study(tmp_path, "t", {3: 1.994, 1: 2.006}, 2.0)
    assert runs.choose_run(runs.load_study("t"))["seed"] == 3  # 1.99 < 2.01


def test_the_first_is_the_lowest_mean_evaluation_error_of_a_study_of_three_seeds(
        runs, tmp_path, capsys):
    write_study(tmp_path, "lucky", {1: 1.50, 2: 2.60, 3: 2.60}, 1.0)  # one lucky seed
    write_study(tmp_path, "steady", {1: 2.00, 2: 2.01, 3: 2.02}, 3.0)
    write_study(tmp_path, "single", {1: 1.00}, 0.5)  # one seed is not enough
    runs.rank(runs.Args(command="rank"))
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    names = [line.split("|")[1].strip() for line in lines[1:]]
    # ordered by mean evaluation error, the headline never chosen on test numbers
    assert names == ["single", "steady **first**", "lucky"]


def test_bias_py_splits_a_known_offset_from_a_known_wobble(monkeypatch):
    spec = importlib.util.spec_from_file_location("bias_study", ROOT / "studies" / "bias.py")
    bias = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, bias)
    spec.loader.exec_module(bias)
    from panda_lead.rollout import Rollout

    n = 500
    t = 0.01 * np.arange(1, n + 1)
    target = np.stack([0.3 + 0.1 * np.cos(t), 0.1 * np.sin(t), 0.5 + 0 * t], axis=1)
    wobble = 0.002 * (-1.0) ** np.arange(n)  # 2 mm, flipping sign every step
    ee = target + np.array([0.01, 0.0, 0.0]) + np.stack([0 * t, wobble, 0 * t], axis=1)
    z3 = np.zeros((n, 3))
    r = Rollout(t=t, ee_pos=ee, target_pos=target, target_vel=z3, target_acc=z3, lead=z3,
                qpos=np.zeros((n, 7)), qvel=np.zeros((n, 7)), self_collision=np.zeros(n, bool),
                collision_depth=np.zeros(n), reachable=np.ones(n, bool),
                meta={"seed": 0, "shape": "circle"})
    settled, offset, fast = bias.parts(r)
    assert offset == pytest.approx(1.0, abs=1e-3)  # cm: the constant 1 cm offset
    assert fast == pytest.approx(0.2, rel=0.1)  # cm: the 2 mm step-to-step wobble
    assert settled == pytest.approx(np.hypot(1.0, 0.2), rel=1e-3)
    # A lead that flips between +1 cm and -1 cm in y every step: a 20 mm step, a 40 mm second
    # difference (a chatter); a lead that drifts steadily: a step, no second difference.
    flip = np.stack([0 * t, 0.01 * (-1.0) ** np.arange(n), 0 * t], axis=1)
    drift = np.stack([0.001 * np.arange(n), 0 * t, 0 * t], axis=1)
    for lead, expected in ((flip, (20.0, 40.0)), (drift, (1.0, 0.0))):
        r.lead = lead
        assert bias.lead_steps(r) == pytest.approx(expected, abs=1e-9)
    # --agreement: a lead 3 cm off another's everywhere differs by 3 cm, all of it constant;
    # one that flips +-1 cm around it differs by 1 cm RMS and by nothing constant
    import copy

    ref = copy.copy(r)
    ref.lead = np.tile([0.04, 0.0, 0.0], (n, 1))
    shifted, flipped = copy.copy(r), copy.copy(r)
    shifted.lead = ref.lead + [0.0, 0.0, 0.03]
    flipped.lead = ref.lead + flip
    assert bias.lead_agreement(shifted, ref) == pytest.approx((4.0, 3.0, 3.0), abs=1e-9)
    lead_rms, rms, const = bias.lead_agreement(flipped, ref)
    assert (lead_rms, rms) == pytest.approx((4.0, 1.0), abs=1e-9) and const < 0.01


def test_curve_draws_the_studies_beside_references_computed_on_the_same_episodes(
        runs, tmp_path, capsys):
    for study, steps in (("a", 100), ("b", 100), ("other", 200)):
        (tmp_path / study).mkdir()
        summary = {"seed": 1, "train_config": {"eval_steps": steps},
                   "eval_curve": [[50_000, 9.0], [100_000, 5.0], [150_000, 4.0]]}
        (tmp_path / study / "seed_1.json").write_text(json.dumps(summary))
    plot = tmp_path / "curve.png"
    runs.curve(runs.Args(command="curve", studies=["a", "b"], plot=plot))
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out, err = capsys.readouterr()
    assert err.strip() == f"wrote {plot}"  # stdout is the table (results.py writes it to the table)
    refs = dict(line.split(": ") for line in out.splitlines()[0:2])
    classical, analytic = (float(refs[k].split()[0]) for k in ("classical", "analytic lead"))
    assert analytic < classical  # the analytic lead leads the target: it tracks better
    with pytest.raises(runs.UserError, match="different lengths"):  # not one evaluation set
        runs.curve(runs.Args(command="curve", studies=["a", "other"], plot=plot, force=True))


def test_choose_looks_for_the_chosen_run_in_every_folder_given(runs, tmp_path):
    """A study whose seeds ran in two sweep folders (seeds 4-5 of the side studies): the chosen
    run is looked for in each; in none of them is one line naming them, nothing archived."""
    write_study(tmp_path, "s", {1: 2.5, 4: 2.2}, 2.0)  # seed 4 (run r4) is chosen
    a, b = tmp_path / "a", tmp_path / "b"
    (a / "r1").mkdir(parents=True)
    b.mkdir()
    with pytest.raises(runs.UserError, match=r"run r4 is in none of .*'.*a', '.*b'"):
        runs.choose(runs.Args(command="choose", study="s", archive_as="x", runs=[a, b]))
    with pytest.raises(runs.UserError, match="needs --runs"):
        runs.choose(runs.Args(command="choose", study="s", archive_as="x"))


def test_time_to_quality_counts_steps_to_the_first_evaluation_under_the_bar(runs):
    """The bar is the classical evaluation error less the margin; a seed that never gets under
    it is 'never' (and ranks last), and the first study is tested for getting there sooner."""
    def seed(*errors):
        return {"eval_curve": [[50_000 * (i + 1), e] for i, e in enumerate(errors)]}

    fast = [seed(4.8, 4.0), seed(4.9, 3.0), seed(4.2, 3.9)]
    slow = [seed(6.0, 5.5, 4.5), seed(6.0, 4.95, 4.4), seed(6.1, 5.2, 5.1)]
    table = runs.time_to_quality({"fast": fast, "slow": slow}, classical_cm=6.41, margin_cm=1.5)
    assert "under 4.91 cm" in table
    assert "| fast | 50, 50, 50 | 50k |" in table  # 4.90 is under 4.91
    assert "| slow | 150, 150, never | 150k |" in table
    p = float(table.rsplit("p = ", 1)[1].split()[0])
    assert p < 0.05  # every fast seed before every slow one: 1/20 by exact ranks, less with ties
    assert runs.first_below([[50_000, 5.0]], 4.0) == float("inf")
    lone = runs.time_to_quality({"long": [seed(6.0)], "short": [seed(4.0)]}, 6.41, 1.5)
    assert "| long | never | never |" in lone and "p = " not in lone
    assert "one seed each side is too few" in lone


def test_a_stopped_runs_curve_is_read_from_its_diagnostics_evaluation_rows(runs, tmp_path):
    stopped = tmp_path / "came_apart_diagnostics.csv"
    head = ",".join(runs.DIAGNOSTICS) + "\n"  # the columns `runs diagnostics --csv` writes
    stopped.write_text(head + "8192,,,0.3,,,\n50000,50000,7.5,,,,\n90112,,,0.2,,,\n"
                       "100000,100000,6.25,,,,\n")
    steps, error = runs.stopped_curve(stopped)
    assert steps.tolist() == [50_000, 100_000] and error.tolist() == [7.5, 6.25]
    # A file with no evaluation rows, or none at all, is one line before any work is done.
    updates_only = tmp_path / "updates_only.csv"
    updates_only.write_text(head + "8192,,,0.3,0.01,0.1,-90\n")
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "seed_1.json").write_text(json.dumps(
        {"seed": 1, "train_config": {"eval_steps": 100}, "eval_curve": [[50_000, 9.0]]}))
    for bad, message in ((updates_only, "no evaluation rows"), (tmp_path / "x.csv", "no such")):
        with pytest.raises(runs.UserError, match=message):
            runs.curve(runs.Args(command="curve", studies=["a"], plot=tmp_path / "c.png",
                                 stopped=[bad]))
    assert not (tmp_path / "c.png").exists()


def test_diagnostics_keep_every_evaluation_and_every_8th_update_and_average_per_window(
        runs, tmp_path, capsys):
    import csv

    run = tmp_path / "run"
    (run / "tb").mkdir(parents=True)
    head = ["time/total_timesteps", "train/std", "train/approx_kl", "train/clip_fraction",
            "rollout/ep_rew_mean", "eval/timesteps", "eval/mean_error_cm", "train/loss"]
    rows = []
    for i in range(1, 21):  # updates at 100k, 200k, ... 2M steps; the std halves at 1M
        rows.append([i * 100_000, 0.4 if i <= 10 else 0.2, 0.01 * i, 0.1, -5, "", "", 1])
        if i % 5 == 0:  # an evaluation every 500k: 8 cm before 1M, 4 cm after
            rows.append(["", 0.3, 0.5, 0.5, "", i * 100_000, 8.0 if i <= 10 else 4.0, ""])
    with open(run / "tb" / "progress.csv", "w", newline="") as f:
        csv.writer(f).writerows([head, *rows])
    out = tmp_path / "diag.csv"
    runs.diagnostics(runs.Args("diagnostics", runs=[run], csv=out, window=1_000_000))
    kept = list(csv.DictReader(open(out)))
    assert [r["total_timesteps"] for r in kept if r["total_timesteps"]] == ["100000", "900000",
                                                                             "1700000"]
    assert [r["mean_error_cm"] for r in kept if r["eval_timesteps"]] == ["8.0"] * 2 + ["4.0"] * 2
    table = capsys.readouterr().out
    assert "| 0-1 | 8 | 0.4 | 0.05 | 0.1 |" in table  # updates at 100k and 900k: KL 0.01, 0.09
    assert "| 1-2 | 4 | 0.2 | 0.17 | 0.1 |" in table  # 1.7M alone
    with pytest.raises(runs.UserError, match="exists"):  # never overwritten unasked
        runs.diagnostics(runs.Args("diagnostics", runs=[run], csv=out))
    out.write_text("a,b\n1,2\n")
    with pytest.raises(runs.UserError, match="not a diagnostics file"):
        runs.diagnostics(runs.Args("diagnostics", csv=out))


def test_keep_commits_every_seed_only_if_it_is_the_model_its_summary_measured(
        runs, tmp_path, monkeypatch, capsys):
    import shutil

    from panda_lead.models import verify

    sweep = tmp_path / "sweep"
    for seed, name in ((1, "indep_v5"), (2, "noisy")):  # two real models as two runs' best
        (sweep / f"r{seed}").mkdir(parents=True)
        shutil.copy2(ROOT / "archive" / f"{name}.zip", sweep / f"r{seed}" / "best_model.zip")
        shutil.copy2(ROOT / "archive" / f"{name}.json", sweep / f"r{seed}" / "best_model.json")
    write_study(tmp_path, "s", {1: 2.0, 2: 2.1}, 2.0)
    monkeypatch.setattr(runs, "SEEDS_DIR", tmp_path / "kept")
    with pytest.raises(runs.UserError, match="seed_1.json summarizes"):  # the summary's hash is 0s
        runs.keep(runs.Args("keep", study="s", runs=[sweep]))
    assert not list((tmp_path / "kept").glob("*.zip"))
    for seed in (1, 2):  # the summaries name the models the runs hold
        f = tmp_path / "s" / f"seed_{seed}.json"
        summary = json.loads(f.read_text())
        summary["best_model_sha256"] = verify(sweep / f"r{seed}" / "best_model.zip")["model_sha256"]
        f.write_text(json.dumps(summary))
    runs.keep(runs.Args("keep", study="s", runs=[sweep]))
    kept = tmp_path / "kept" / "s_s2.zip"
    side = verify(kept)  # a valid pair, loadable by every script
    assert (side["study"], side["seed"]) == ("s", 2)
    assert side["env_config"] == verify(ROOT / "archive" / "noisy.zip")["env_config"]
    capsys.readouterr()
    runs.keep(runs.Args("keep", study="s", runs=[sweep]))  # never replaced unasked
    assert capsys.readouterr().out.count("exists") == 2
    # a seed kept as its summary's model needs no run folder (a study grown elsewhere)
    shutil.rmtree(sweep / "r1")
    runs.keep(runs.Args("keep", study="s", runs=[sweep]))
    assert capsys.readouterr().out.count("the model its summary measured") == 2
    with pytest.raises(runs.UserError, match="r1"):  # replacing it does need the run
        runs.keep(runs.Args("keep", study="s", runs=[sweep], force=True))


def test_a_study_is_compared_with_a_rival_from_the_baselines_file(runs, tmp_path, capsys):
    """Issue 37: the classical rivals that know the planned path are baselines a study is
    compared with (`compare --against-study baseline:feedforward`), with the study's seed spread
    in the CI and none on the rival's side; an unknown rival is one clear line."""
    from panda_lead.errors import UserError

    write_study(tmp_path, "preview", {1: 2.0, 2: 2.1, 3: 2.2}, 1.0)
    ff = {"mean_err": [1.5, 1.4, 1.6, 1.5], "settled_err": [1.0] * 4, "jerk_rms": [2.0] * 4}
    (tmp_path / "baselines.json").write_text(json.dumps({"test_seeds": "0-3", "feedforward": ff}))
    runs.compare_studies(runs.Args(command="compare", study="preview",
                                   against_study="baseline:feedforward", bootstrap=200))
    row = next(line for line in capsys.readouterr().out.splitlines()
               if line.startswith("| mean error"))
    cells = [c.strip() for c in row.split("|")]
    assert cells[2:4] == ["1.500", "1.000"] and cells[4].startswith("-0.500")
    with pytest.raises(UserError, match="unknown baseline 'feedfwd'.*feedforward"):
        runs.compare_studies(runs.Args(command="compare", study="preview",
                                       against_study="baseline:feedfwd"))


def test_compare_by_shape_finds_a_difference_where_it_is(runs, tmp_path, capsys):
    """--by-shape: the same paired differences within each target shape (the shape each test
    seed draws); a study worse by 1 cm on one shape's trajectories only is worse there, equal
    on the others, and worse by that shape's share overall."""
    from panda_lead.trajectory import sample

    shapes = [sample(s).shape for s in range(12)]
    worse = shapes[0]
    for study, extra in (("a", 0.0), ("b", 1.0)):
        (tmp_path / study).mkdir()
        for seed in (1, 2, 3):
            err = [2.0 + 0.01 * seed + (extra if sh == worse else 0.0) for sh in shapes]
            (tmp_path / study / f"seed_{seed}.json").write_text(json.dumps(
                {"seed": seed, "run": f"r{seed}", "best": {"mean_error_cm": 2.0, "timesteps": 1},
                 "best_model_sha256": "0" * 64, "timesteps": 1, "test_seeds": "0-11",
                 "test": {"mean_err": err, "settled_err": err, "jerk_rms": [1.0] * 12}}))
    runs.compare_studies(runs.Args(command="compare", study="b", against_study="a",
                                   bootstrap=200, by_shape=True))
    out = capsys.readouterr().out
    diff = {line.split("|")[1].strip(): float(line.split("|")[4].split()[0])
            for line in out.splitlines() if "error |" in line}
    share = shapes.count(worse) / 12
    assert diff["mean error"] == pytest.approx(share, abs=1e-3)  # printed to 0.001 cm
    assert diff[f"{worse} (n={shapes.count(worse)}): mean error"] == pytest.approx(1.0)
    for other in set(shapes) - {worse}:
        assert diff[f"{other} (n={shapes.count(other)}): settled error"] == pytest.approx(0.0)
    assert "--by-shape" in out


def test_baselines_computes_only_the_rivals_the_file_lacks(runs, tmp_path, monkeypatch):
    """Adding a rival to BASELINES costs that rival's rollouts, not every baseline's again;
    with nothing missing the command says so, and --force recomputes all."""
    from panda_lead import harness
    from panda_lead.errors import UserError

    played = []
    monkeypatch.setattr(harness, "build", lambda kind, *a, **k: kind)
    monkeypatch.setattr(runs, "_metrics_on_test", lambda kind: played.append(kind) or
                        {"mean_err": [float(len(played))]})
    monkeypatch.setattr(runs, "_tau_500hz", lambda: 0.03)
    kept = {"mean_err": [9.0]}
    old = {"test_seeds": runs.TEST, **{name: kept for name in runs.BASELINES
                                       if name not in runs.KNOWS_PATH}}
    (tmp_path / "baselines.json").write_text(json.dumps(old))
    runs.baselines(runs.Args(command="baselines"))
    assert played == ["future_target", "feedforward", "feedforward_plan"]
    out = json.loads((tmp_path / "baselines.json").read_text())
    assert out["classical"] == kept and out["feedforward"] == {"mean_err": [2.0]}
    with pytest.raises(UserError, match="has every baseline; add --force"):
        runs.baselines(runs.Args(command="baselines"))
    played.clear()
    runs.baselines(runs.Args(command="baselines", force=True))
    assert len(played) == len(runs.BASELINES)


def test_a_study_that_knows_the_path_is_never_first(runs, tmp_path, capsys):
    """Issue 37: the preview variant is ranked apart, after the causal studies, however low its
    evaluation errors."""
    write_study(tmp_path, "causal", {1: 2.0, 2: 2.0, 3: 2.0}, 2.0)
    write_study(tmp_path, "ahead", {1: 1.0, 2: 1.0, 3: 1.0}, 1.0)
    for f in (tmp_path / "ahead").glob("seed_*.json"):
        summary = json.loads(f.read_text())
        summary["train_config"] = {"env": {"obs_features": ["tip_error", "target_preview"]}}
        f.write_text(json.dumps(summary))
    runs.rank(runs.Args(command="rank"))
    out = capsys.readouterr().out
    causal, apart = out.split("KNOWS THE PLANNED PATH")
    assert "| causal **first** |" in causal and "ahead" not in causal
    assert "| ahead |" in apart
