"""Reliability round 4, the study scripts (../shared/RELIABILITY-4.md, items named per test):
studies/runs.py, collision.py, robustness.py, ilc_tune.py, rederive.py and bias.py keep the
root scripts' promises: one `error:` line and exit 2 on bad input, every value checked before
any work, nothing overwritten without --force (and two runs on one output cannot both write),
bounded reads of the files they trust, no NaN ranking or choosing, a chosen run bound to its
summary by name and hash, models played as the evaluation harness plays them."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import ROOT, one_line, run_in_process, run_script

from panda_lead.atomicio import file_lock
from panda_lead.errors import UserError, printable
from panda_lead.outputs import output_lock_path

MODEL = ROOT / "archive" / "indep_v5.zip"


def load(name: str, monkeypatch):
    spec = importlib.util.spec_from_file_location(f"{name}_study", ROOT / "studies" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def runs(tmp_path, monkeypatch):
    module = load("runs", monkeypatch)
    monkeypatch.setattr(module, "RUNS_DIR", tmp_path)
    return module


def summary(seed: int, best: float = 2.0, n: int = 4, **extra) -> dict:
    return {"seed": seed, "run": f"r{seed}", "best": {"mean_error_cm": best, "timesteps": 1},
            "best_model_sha256": "0" * 64, "timesteps": 1, "test_seeds": f"0-{n - 1}",
            "test": {"mean_err": [2.0] * n, "settled_err": [1.0] * n, "jerk_rms": [1.0] * n},
            "train_config": {"eval_steps": 10}, "eval_curve": [[50_000, 5.0]], **extra}


def write(root, study: str, *summaries: dict, raw: dict | None = None) -> None:
    (root / study).mkdir(exist_ok=True)
    for s in summaries:
        (root / study / f"seed_{s['seed']}.json").write_text(json.dumps(s))
    for name, text in (raw or {}).items():
        (root / study / name).write_text(text)


def write_baselines(root, n: int = 4) -> None:
    lists = {"mean_err": [3.0] * n, "settled_err": [2.0] * n, "jerk_rms": [1.0] * n}
    (root / "baselines.json").write_text(json.dumps(
        {"test_seeds": f"0-{n - 1}", "analytic": lists, "classical": lists}))


# --- runs.py -------------------------------------------------------------------------------

def test_12_a_nan_best_never_ranks_or_chooses(runs, tmp_path, capsys):
    """A NaN best in a study's first seed was chosen (min() on NaN), and one NaN seed moved the
    headline; now the summary is refused by name before anything is printed."""
    good = [summary(2, 2.5), summary(3, 2.6)]
    for token in ("NaN", "Infinity", "1e999"):
        write(tmp_path, "s", *good, raw={"seed_1.json": json.dumps(summary(1)).replace(
            '"mean_error_cm": 2.0', f'"mean_error_cm": {token}')})
        with pytest.raises(UserError, match="seed_1.json"):
            runs.choose_run(runs.load_study("s"))
        with pytest.raises(UserError, match="seed_1.json"):
            runs.rank(runs.Args(command="rank"))
    assert "**first**" not in capsys.readouterr().out
    with pytest.raises(UserError, match="not a finite number"):  # the last guard, in the rule
        runs.choose_run([{"seed": 1, "best": {"mean_error_cm": math.nan}}, summary(2, 2.5)])


def test_13_a_truncated_test_list_is_refused_not_broadcast(runs, tmp_path, capsys):
    short = summary(1)
    short["test"]["mean_err"] = [1.3]  # one value where the test seeds are four
    write(tmp_path, "s", short, summary(2))
    write_baselines(tmp_path)
    with pytest.raises(UserError, match=r"seed_1.json.*test.mean_err must hold 4 values"):
        runs.report(runs.Args(command="report", study="s", bootstrap=100))
    assert capsys.readouterr().out == ""
    write(tmp_path, "s", summary(1))  # repaired; the baseline over other seeds is refused
    write_baselines(tmp_path, n=5)
    with pytest.raises(UserError, match="different test seeds"):
        runs.report(runs.Args(command="report", study="s", bootstrap=100))


@pytest.mark.parametrize("text, words", [
    ('{"seed": 1, "best": ', "not a run summary"),
    (json.dumps({k: v for k, v in summary(1).items() if k != "seed"}), "seed must be"),
    (json.dumps({**summary(1), "best": "2.0"}), "best must be an object"),
    (json.dumps({**summary(1, n=999), "test_seeds": "0-3"}), "must hold 4 values"),
    (json.dumps({**summary(1), "seed": 5}), "its file must be seed_5.json"),
    ("[" * 5000 + "]" * 5000, "seed_1.json"),
    (b"\xff\xfe{}", "not a run summary"),
])
def test_20_a_damaged_summary_is_one_line_before_any_row(runs, tmp_path, capsys, text, words):
    write(tmp_path, "s", summary(2), summary(3))
    path = tmp_path / "s" / "seed_1.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    write_baselines(tmp_path)
    # (choose reads the best evaluations only: a test list is report's and rank's to refuse)
    for command in ("report", "rank", *(() if "values" in words else ("choose",))):
        with pytest.raises(UserError, match=words):
            getattr(runs, command)(runs.Args(command=command, study="s", bootstrap=100))
    assert capsys.readouterr().out == ""  # nothing half-printed


def test_20_compare_refuses_studies_on_other_test_seeds(runs, tmp_path):
    write(tmp_path, "a", summary(1), summary(2))
    write(tmp_path, "b", summary(1, n=3), summary(2, n=3))
    with pytest.raises(UserError, match="different test seeds"):
        runs.compare_studies(runs.Args(command="compare", study="b", against_study="a",
                                       bootstrap=100))


def test_18_summaries_are_read_with_a_size_bound(runs, tmp_path, monkeypatch):
    """A summary linked to /dev/zero took 2.7 GB before MemoryError (not reproduced here: on
    the old code it takes the machine's memory); now only a regular file is read, at most the
    bound plus one byte, by one reader shared with rederive.py."""
    from panda_lead import summaries

    write(tmp_path, "s", summary(2))
    (tmp_path / "s" / "seed_1.json").symlink_to(tmp_path)  # a folder, as /dev/zero a device
    with pytest.raises(UserError, match="not a regular file"):
        runs.load_study("s")
    (tmp_path / "s" / "seed_1.json").unlink()
    with open(tmp_path / "s" / "seed_1.json", "wb") as f:  # sparse: no disk, 1 byte too many
        f.truncate(summaries.MAX_SUMMARY_BYTES + 1)
    with pytest.raises(UserError, match="over 8,388,608 bytes"):
        runs.load_study("s")
    rederive = load("rederive", monkeypatch)
    assert rederive.read_json is summaries.read_json  # the same reader
    monkeypatch.setattr(rederive, "RUNS_DIR", tmp_path)
    with pytest.raises(UserError, match="over 8,388,608 bytes"):
        rederive.load_summary("s", 1)


def test_14_choose_archives_only_the_run_the_summary_names_and_hashes(
        runs, tmp_path, monkeypatch):
    """The run's name must be a plain name inside --runs, and the model there must have the
    summary's best_model_sha256; nothing is archived otherwise."""
    from panda_lead.models import verify
    from panda_lead.training import archive

    sweep = tmp_path / "sweep"
    for run, name in (("r7", "indep_v5"), ("r8", "noisy")):
        (sweep / run).mkdir(parents=True)
        for ext in ("zip", "json"):
            shutil.copy2(ROOT / "archive" / f"{name}.{ext}", sweep / run / f"best_model.{ext}")
    archived = []
    monkeypatch.setattr(archive, "archive_model",
                        lambda run_dir, name, force=False: archived.append(run_dir) or run_dir)
    sha7 = verify(sweep / "r7" / "best_model.zip")["model_sha256"]
    args = runs.Args(command="choose", study="s", archive_as="x_never_written", runs=[sweep])
    for run, words in (("../../x", "run must be a plain name"), ("r8", "SHA-256 differs")):
        write(tmp_path, "s", {**summary(7), "run": run, "best_model_sha256": sha7})
        with pytest.raises(UserError, match=words):
            runs.choose(args)
    assert archived == []
    write(tmp_path, "s", {**summary(7), "run": "r7", "best_model_sha256": sha7})
    runs.choose(args)
    assert archived == [sweep / "r7"]


def test_4_curve_never_replaces_a_plot_without_force(runs, tmp_path):
    write(tmp_path, "a", summary(1))
    plot = tmp_path / "p.png"
    plot.write_text("mine")
    with pytest.raises(UserError, match="exists; add --force"):
        runs.curve(runs.Args(command="curve", studies=["a"], plot=plot))
    assert plot.read_text() == "mine"


def test_22_curve_and_summarize_on_damaged_inputs_are_one_line(runs, tmp_path):
    write(tmp_path, "a", summary(1, eval_curve=[]))
    with pytest.raises(UserError, match="eval_curve must be a non-empty list"):
        runs.curve(runs.Args(command="curve", studies=["a"], plot=tmp_path / "c.png"))
    run = tmp_path / "run"
    (run / "tb").mkdir(parents=True)
    for model in ("best_model", "final_model"):
        for ext in ("zip", "json"):
            shutil.copy2(ROOT / "archive" / f"indep_v5.{ext}", run / f"{model}.{ext}")
    (run / "tb" / "progress.csv").write_text("eval/timesteps,eval/mean_error_cm\n50000,lots\n")
    with pytest.raises(UserError, match="progress.csv: not a readable training log"):
        runs.summarize(runs.Args(command="summarize", study="t", runs=[run]))
    assert not (tmp_path / "t" / "seed_42.json").exists()


def test_22_the_summarized_best_is_the_best_models_own_not_best_json(runs, tmp_path):
    """best.json is bound to nothing (deleted or edited, summarize copied it or crashed); the
    best is read from the best model's sidecar, which its hash binds."""
    from panda_lead.models import verify

    side = verify(MODEL)
    run = tmp_path / "run"
    run.mkdir()
    best = runs._run_best(run, side)  # no best.json at all
    assert best["mean_error_cm"] == side["eval_metrics"]["mean_error_cm"]
    (run / "best.json").write_text(json.dumps({"timesteps": 1, "mean_error_cm": -1.0}))
    assert runs._run_best(run, side) == best
    old = {k: v for k, v in side.items() if k != "eval_metrics"}  # a model saved without it
    (run / "best.json").unlink()
    with pytest.raises(UserError, match="best.json: no such file"):
        runs._run_best(run, old)


@pytest.mark.parametrize("window, row, words", [
    (0, "50000,50000,7.5,,,,", "--window must be"),
    (-1_000_000, "50000,50000,7.5,,,,", "--window must be"),  # 35: labels like "2-1"
    (1_000_000, "inf,,,0.3,,,", "not a finite number"),
    (1_000_000, "lots,,,0.3,,,", "not a finite number"),
    (1_000_000, b"\xff\xfe,,,0.3,,,", "not a diagnostics file"),
])
def test_21_35_diagnostics_refuse_bad_windows_and_cells(runs, tmp_path, window, row, words):
    path = tmp_path / "d.csv"
    head = ",".join(runs.DIAGNOSTICS) + "\n"
    row = row if isinstance(row, bytes) else row.encode()
    path.write_bytes(head.encode() + row + b"\n")
    with pytest.raises(UserError, match=words):
        runs.diagnostics(runs.Args("diagnostics", csv=path, window=window))


# --- writers: one output, one writer (3) ---------------------------------------------------

def test_3_a_second_run_on_one_out_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    """Two collision.py (robustness.py, ilc_tune.py) runs on one --out both passed the up-front
    check and the second replaced the first's table; now the first holds the output's lock and
    the second is one line, before it plays anything."""
    subset = tmp_path / "subset.txt"
    subset.write_text("".join(f"{s}\n" for s in range(10)))
    cases = {
        "collision": lambda m, out: m.Args(models=[MODEL], subset=subset, out=out),
        "robustness": lambda m, out: m.Args(models=[MODEL], levels=[0.0], seeds="0-1",
                                            out=out.parent, bootstrap=100),
        "ilc_tune": lambda m, out: m.Args(inits=["zero"], gains=[0.5], shifts=[2],
                                          iterations=1, duration=0.1, model=MODEL, out=out),
    }
    for name, make in cases.items():
        module = load(name, monkeypatch)
        out = tmp_path / name / ("noise.md" if name == "robustness" else "t.md")
        with file_lock(output_lock_path(out), "a first run"):  # a first run, writing
            with pytest.raises(SystemExit) as exc:
                module.main(make(module, out))
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "in use by another process" in err[0], err
        assert not out.exists()


def test_3_claimed_outputs_recheck_under_the_lock(tmp_path):
    from panda_lead.outputs import claimed_outputs

    out = tmp_path / "t.md"
    with claimed_outputs([out], "--out", force=False):
        out.write_text("first")  # the first run finished while the second waited
    with pytest.raises(UserError, match="exists; add --force"):
        with claimed_outputs([out], "--out", force=False):
            pass
    with claimed_outputs([out], "--out", force=True):
        pass


# --- robustness.py, ilc_tune.py: values checked before any work (31), one line (29, 32) ------

@pytest.mark.parametrize("kwargs, words", [
    ({"question": "noise", "levels": [0.0, -1.0]}, "noise levels are sigmas"),
    ({"question": "noise", "levels": [0.0, math.nan]}, "noise levels are sigmas"),
    ({"question": "delay", "levels": [0.0, 1.5]}, "whole control steps"),
    ({"question": "delay", "levels": [1.0, 1.0]}, "names a level twice"),
    ({"bootstrap": 5}, "--bootstrap must be"),
])
def test_31_robustness_checks_every_value_before_playing(monkeypatch, kwargs, words):
    robustness = load("robustness", monkeypatch)
    played = []
    monkeypatch.setattr(robustness, "play", lambda *a: played.append(a))
    with pytest.raises(UserError, match=words):
        robustness.plan(robustness.Args(models=[MODEL], seeds="0-1", **kwargs))
    assert played == []


def test_31_robustness_out_a_file_is_one_line_before_playing(tmp_path, monkeypatch, capsys):
    robustness = load("robustness", monkeypatch)
    monkeypatch.setattr(robustness, "play", lambda *a: pytest.fail("played"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(SystemExit):
        robustness.main(robustness.Args(models=[MODEL], seeds="0-1", bootstrap=100,
                                        levels=[0.0], out=tmp_path / "file"))
    assert "is a file, not a folder" in capsys.readouterr().err


@pytest.mark.parametrize("kwargs, words", [
    ({"inits": ["zero", "bogus"]}, "unknown first replay 'bogus'"),
    ({"shifts": [2, 99]}, r"--shifts must be in \[0, 50\], got 99"),
    ({"gains": [0.5, -1.0]}, "--gains must be"),
    ({"duration": math.nan}, "--duration must be"),
    ({"inits": []}, "--inits needs at least one"),
])
def test_31_ilc_tune_checks_the_whole_grid_before_the_first_replay(monkeypatch, kwargs, words):
    ilc_tune = load("ilc_tune", monkeypatch)
    with pytest.raises(UserError, match=words):
        ilc_tune.grid(ilc_tune.Args(**kwargs))


@pytest.mark.parametrize("script, args, words", [
    ("studies/robustness.py", ["--question", "nois"], "--question"),  # 32
    ("studies/collision.py", ["--modles", "x"], "--modles"),  # 32
    ("studies/ilc_tune.py", ["--gains", "x"], "--gains"),  # 32
    ("studies/ilc_tune.py", ["--duration", "nan"], "--duration"),  # 29
    ("studies/bias.py", ["--prefixes"], "--prefixes"),  # 29
    ("studies/robustness.py", ["--levels", "0", "-1", "--models", str(MODEL)], "noise levels"),
])
def test_29_32_bad_command_lines_are_one_error_line(script, args, words):
    one_line(run_in_process(script, *args), words)  # as the script's command line, in-process


def test_29_32_a_bad_command_line_is_one_line_and_exit_2_from_the_process():
    one_line(run_script("studies/robustness.py", "--question", "nois"), "--question")


# --- collision.py: models through the harness (15) -----------------------------------------

def test_15_collision_plays_models_with_their_evaluation_settings(tmp_path, monkeypatch):
    """A model trained with a random 3-step delay played with it (3.94 cm, 4.34 through
    eval.py), and "+ clearance" replaced the model's whole IK block; now each controller is the
    harness's, and the clearance row differs from its plain row in ik.clearance alone."""
    from panda_lead import harness
    from panda_lead.models import copy_with_sidecar, verify

    collision = load("collision", monkeypatch)
    side = verify(ROOT / "archive" / "delayed.zip")
    env = {**side["env_config"], "ik": {"damping": 0.1, "substep_ik": True}}
    model = tmp_path / "delayed_ik.zip"
    copy_with_sidecar(ROOT / "archive" / "delayed.zip", model, {"env_config": env})
    ctrls, labels = collision.build_controllers([model], 0.02)
    plain, aware = ctrls["delayed_ik"].config, ctrls["delayed_ik + clearance"].config
    assert plain == harness.build("policy", 500, model).config  # as eval.py plays it
    assert (plain.obs_delay, plain.action_delay, plain.random_delay) == (0, 0, False)
    assert not plain.terminate_on_collision
    assert (aware.ik.damping, aware.ik.substep_ik, aware.ik.clearance) == (0.1, True, 0.02)
    assert aware.replace(ik=plain.ik) == plain  # nothing but the IK ...
    assert {**dataclasses.asdict(aware.ik), "clearance": 0.0} == \
        {**dataclasses.asdict(plain.ik), "clearance": 0.0}  # ... and of it, the clearance
    assert ctrls["Classical + clearance"].config.ik.clearance == 0.02
    with pytest.raises(UserError, match="--clearance must be"):
        collision.build_controllers([model], -0.02)


def test_collision_subset_file_is_checked_and_bounded(tmp_path, monkeypatch):
    collision = load("collision", monkeypatch)
    subset = tmp_path / "s.txt"
    for text, words in (("1\n2\nx\n", "cannot read"), ("1\n" * 12, "names a seed twice"),
                        ("1\n2\n", "too few"), ("-5\n" + "1\n" * 10, "a seed must be")):
        subset.write_text(text)
        with pytest.raises(UserError, match=words):
            collision.read_subset(subset)


# --- bias.py: metrics.py's set checks, failures charged (11) -------------------------------

@pytest.fixture(scope="module")
def rollout_root(tmp_path_factory):
    """Classical and analytic sets of 1 s and a classical set of 1.5 s on seeds 0-2."""
    from panda_lead import harness

    root = tmp_path_factory.mktemp("rollouts")
    for prefix, name, steps in (("c", "classical", 100), ("a", "analytic", 100),
                                ("c_long", "classical", 150)):
        harness.write_set(harness.build(name, steps), [0, 1, 2], None, root, prefix,
                          echo=lambda *_: None)
    return root


def test_11_bias_refuses_what_metrics_py_refuses(rollout_root, tmp_path, monkeypatch):
    bias = load("bias", monkeypatch)
    with pytest.raises(UserError, match="duration differs"):
        bias.load_sets(["c", "c_long"], rollout_root)
    mixed = tmp_path / "mixed"
    shutil.copytree(rollout_root / "c", mixed)
    shutil.copy2(rollout_root / "a" / "seed_0001.npz", mixed / "seed_0001.npz")
    with pytest.raises(UserError, match="mixes 2 controllers"):
        bias.load_sets(["mixed"], tmp_path)
    with pytest.raises(UserError, match="at least one"):
        bias.load_sets([], rollout_root)


def test_11_bias_charges_a_failed_episode(rollout_root, tmp_path, monkeypatch, capsys):
    from panda_lead import rollout

    bias = load("bias", monkeypatch)
    failed = tmp_path / "failed"
    shutil.copytree(rollout_root / "c", failed)
    r = rollout.load(failed / "seed_0000.npz")
    r.ee_pos = np.array(r.ee_pos, dtype=float)
    r.ee_pos[60:] = np.nan  # the simulation came apart at 0.6 s
    rollout.save(r, failed / "seed_0000.npz")
    shutil.copytree(rollout_root / "c", tmp_path / "c")
    bias.main(bias.Args(prefixes=["c", "failed"], root=tmp_path))
    out, err = capsys.readouterr()
    assert "warning: failed: 1 failed episode(s) charged" in err
    rows = {line.split("|")[3].strip(): line for line in out.splitlines()
            if line.startswith("| all |")}
    settled = {p: float(rows[p].split("|")[4].split()[0]) for p in ("c", "failed")}
    assert all(map(math.isfinite, settled.values())) and settled["failed"] > settled["c"]


# --- rederive.py (23, 33) ------------------------------------------------------------------

@pytest.fixture
def rederive(tmp_path, monkeypatch):
    module = load("rederive", monkeypatch)
    monkeypatch.setattr(module, "RUNS_DIR", tmp_path / "summaries")
    return module


def tiny_config() -> dict:
    from panda_lead.training.config import TrainConfig

    return TrainConfig(timesteps=96, n_envs=2, n_steps=16, batch_size=32, n_epochs=1,
                       eval_freq=32, eval_steps=10, curriculum_steps=0, seed=7,
                       n_workers=1).to_dict()


def write_rederive(folder, config: dict, curve=None, **extra) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "seed_7.json").write_text(json.dumps(
        {"seed": 7, "train_config": config, "eval_curve": curve or [[32, 5.0], [64, 4.0]],
         "commit": "abc", **extra}))


@pytest.mark.parametrize("edit, words", [
    (lambda c, s: s.update(eval_curve=[[1e999, 5.0]]), "not a run summary"),
    (lambda c, s: c.update(net_arch=5), "train_config"),
    (lambda c, s: c.update(curriculum_start_speed="fast"), "train_config"),
    (lambda c, s: c.update(n_envs=0), "train_config: --n-envs"),
    (lambda c, s: s.update(eval_curve=[[32, 5.0], [-64, 4.0]]), "eval_curve step"),
])
def test_23_rederive_refuses_a_damaged_summary_in_one_line(rederive, edit, words):
    config, s = tiny_config(), {}
    edit(config, s)
    folder = rederive.RUNS_DIR / "s"
    folder.mkdir(parents=True)
    body = {"seed": 7, "train_config": config, "eval_curve": [[32, 5.0]], **s}
    (folder / "seed_7.json").write_text(json.dumps(body).replace("Infinity", "1e999"))
    with pytest.raises(UserError, match=words):
        rederive.load_summary("s", 7)
    nested = {"seed": 7, "train_config": config, "eval_curve": [[32, 5.0]],
              "x": json.loads("[" * 200 + "]" * 200)}
    (folder / "seed_7.json").write_text(json.dumps(nested))
    with pytest.raises(UserError, match="nested more than"):
        rederive.load_summary("s", 7)


def test_33_rederive_prints_the_commit_and_cpu_sanitized(rederive):
    write_rederive(rederive.RUNS_DIR / "s", tiny_config(),
                   commit="\x1b[2J\x1b[31mHACKED" + "x" * 5_000_000, cpu="\x1b]0;title\x07cpu")
    loaded = rederive.load_summary("s", 7)
    for text in (loaded["commit"], loaded["cpu"]):
        assert "\x1b" not in text and "\x07" not in text and len(text) <= 200
    assert loaded["commit"].startswith("?[2J?[31mHACKED")
    assert printable("a\nb\u202e", 10) == "a?b?" and printable("x" * 20, 5) == "xxxx\u2026"


def test_23_an_interrupted_rederive_is_one_line_and_leaves_no_folder(rederive, monkeypatch,
                                                                     tmp_path, capsys):
    from panda_lead.training import TrainingInterrupted

    write_rederive(rederive.RUNS_DIR / "s", tiny_config())
    made = []

    def interrupted(config, evals, runs_dir):
        made.append(runs_dir)
        raise TrainingInterrupted(runs_dir / "rederive_x", 32, signal.SIGINT)

    monkeypatch.setattr(rederive, "rerun_curve", interrupted)
    assert rederive.main(rederive.Args(study="s", seed=7)) == 130
    out = capsys.readouterr().out
    assert "interrupted: nothing re-derived" in out and "nothing to resume" in out
    assert made and not made[0].exists()  # the temporary folder is gone


def test_23_sigterm_before_learning_removes_the_temporary_run_folder(tmp_path):
    """SIGTERM's default action killed rederive.py with its rederive_* folder left behind;
    now it unwinds (exit 143) and the folder is removed."""
    work, tmp = tmp_path / "work", tmp_path / "tmp"
    tmp.mkdir()
    write_rederive(work / "results" / "runs" / "s", tiny_config())
    proc = subprocess.Popen([sys.executable, str(ROOT / "studies" / "rederive.py"), "--study",
                             "s", "--seed", "7"], cwd=work, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp), "MUJOCO_GL": "egl"})
    try:
        deadline = time.monotonic() + 120  # a bound on waiting for the event, not a timing
        while not list(tmp.glob("rederive_*")) and proc.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.02)
        assert list(tmp.glob("rederive_*")), "the rerun never made its folder"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "interrupted: nothing re-derived" in out
    assert not list(tmp.glob("rederive_*"))
