"""Bad input to the command lines (issue 25), each answered with one `error:` line and exit
status 2, with nothing the user had lost or half-written and nothing overwritten without
--force: equal labels, existing outputs, seeds beyond int64, read-only folders, paths of the
wrong kind, absurd sizes, tyro's type errors, and the sweep's names, train.py flags and
storages."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line, run_in_process

from panda_lead import rollout
from panda_lead.errors import UserError
from panda_lead.rollout import Rollout

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MUJOCO_GL": "egl", "PYTHONIOENCODING": "utf-8"}
T = 50


def run_process(*args, cwd, timeout=600):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=ENV)


def run(script, *args, cwd, timeout=None):
    """The script in-process (conftest.run_in_process): the same exit status and output,
    without a process per case; the tyro errors and the sweep below run as processes."""
    return run_in_process(script, *args, cwd=cwd)


def a_rollout(seed: int, offset: float = 0.02) -> Rollout:
    t = 0.01 * np.arange(1, T + 1)
    from panda_lead.trajectory import sample  # a file's target must be its seed's to load

    target, vel, acc = sample(seed, "circle").at(t)
    return Rollout(t=t, ee_pos=target + [offset, 0, 0], target_pos=target,
                   target_vel=vel, target_acc=acc,
                   lead=np.zeros((T, 3)), qpos=np.zeros((T, 7)), qvel=np.zeros((T, 7)),
                   self_collision=np.zeros(T, bool), collision_depth=np.zeros(T),
                   reachable=np.ones(T, bool),
                   meta={"seed": seed, "shape": "circle", "controller": "classical",
                         "model": None, "dt": 0.01, "duration": T * 0.01})


@pytest.fixture
def sets(tmp_path) -> Path:
    """rollouts/a and rollouts/b, 12 seeds each (one controller)."""
    root = tmp_path / "rollouts"
    for prefix, offset in (("a", 0.03), ("b", 0.01)):
        for s in range(12):
            rollout.save(a_rollout(s, offset), rollout.rollout_path(prefix, s, root))
    return root


def metrics(root: Path, *args, cwd):
    return run(ROOT / "metrics.py", "--root", root, "--prefix-a", "a", "--prefix-b", "b",
               "--bootstrap", "200", *args, cwd=cwd)


@contextlib.contextmanager
def read_only(folder: Path):
    """A folder nothing can be written into. chmod does not stop root, so as root the folder
    is made immutable (chattr +i, which stops root too); skipped only if neither works."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)
        undo = lambda: folder.chmod(0o755)  # noqa: E731
    else:
        chattr = shutil.which("chattr")
        made = chattr and subprocess.run([chattr, "+i", str(folder)],
                                         capture_output=True).returncode == 0
        if not made:
            pytest.skip("running as root, where chmod does not stop writes, and chattr +i is "
                        "not available on this file system")
        undo = lambda: subprocess.run([chattr, "-i", str(folder)], check=True)  # noqa: E731
    try:
        probe = folder / "probe"
        with contextlib.suppress(OSError):
            probe.write_text("x")
        assert not probe.exists(), "the folder is still writable"
        yield folder
    finally:
        undo()


# --- item 3: two sets under one name -----------------------------------------------------------

def test_equal_labels_are_refused_in_one_line(sets, tmp_path):
    """--label-a X --label-b X folded both sets into one key (and skipped the exclusions)."""
    one_line(metrics(sets, "--label-a", "X", "--label-b", "X", cwd=tmp_path),
             "--label-a and --label-b are both 'X'")
    out = run(ROOT / "metrics.py", "--root", sets, "--prefix-a", "a", "--prefix-b", "a",
              "--bootstrap", "200", cwd=tmp_path)
    one_line(out, "both sets would be named 'a'", "--label-a")
    from panda_lead.cli import metrics as metrics_cli

    with pytest.raises(SystemExit) as exc:
        metrics_cli.run(metrics_cli.Args(root=sets, prefix_a="a", prefix_b="b", label_a="X",
                                         label_b="X", bootstrap=200))
    assert exc.value.code == 2


# --- item 8: nothing is overwritten without --force ---------------------------------------------

def test_metrics_plot_keeps_an_existing_file_without_force(sets, tmp_path):
    png = tmp_path / "cmp.png"
    png.write_bytes(b"mine")
    one_line(metrics(sets, "--plot", png, cwd=tmp_path), "--plot", "exists", "--force")
    assert png.read_bytes() == b"mine"
    ok = metrics(sets, "--plot", png, "--force", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_trajectory_out_keeps_an_existing_file_without_force(tmp_path):
    png = tmp_path / "t.png"
    png.write_bytes(b"mine")
    one_line(run(ROOT / "trajectory.py", "--seed", "3", "--out", png, cwd=tmp_path),
             "--out", "exists", "--force")
    assert png.read_bytes() == b"mine"
    ok = run(ROOT / "trajectory.py", "--seed", "3", "--out", png, "--force", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_eval_video_keeps_an_existing_file_without_force(tmp_path):
    video = tmp_path / "v.mp4"
    video.write_bytes(b"mine")
    out = run(ROOT / "ikpd.py", "--seed", "1", "--video", video, "--duration", "0.1",
              cwd=tmp_path)
    one_line(out, "exists", "--force")
    assert video.read_bytes() == b"mine"


def test_collision_study_keeps_an_existing_table_and_seeds_without_force(tmp_path):
    table, seeds = tmp_path / "c.md", tmp_path / "c_seeds.txt"
    few, enough = tmp_path / "few.txt", tmp_path / "enough.txt"
    few.write_text("1\n2\n3\n")
    enough.write_text("".join(f"{s}\n" for s in range(1, 11)))  # collision.MIN_SUBSET seeds
    table.write_text("mine")
    script = ROOT / "studies" / "collision.py"
    study = (script, "--models", ROOT / "archive" / "v5_5m.zip", "--out", table)
    one_line(run(*study, "--subset", enough, cwd=tmp_path), "c.md exists", "--force")
    # Every value is checked before any output is claimed (RELIABILITY-4 #31): a subset too
    # small is refused first, the table untouched.
    one_line(run(*study, "--subset", few, cwd=tmp_path), "only 3 collision-prone seeds")
    # Finding the subset would write the seeds file beside the table: refused before the scan.
    table.unlink()
    seeds.write_text("7\n")
    one_line(run(*study, cwd=tmp_path), "c_seeds.txt exists", "--force")
    # Reading the seeds back from that file does not write it, so nothing is in the way.
    one_line(run(*study, "--subset", seeds, cwd=tmp_path), "only 1 collision-prone seeds")
    table.write_text("mine")
    # --force passes the check (and stops at the next one: no model named).
    one_line(run(script, "--out", table, "--subset", enough, "--force", cwd=tmp_path),
             "name at least one --models")
    assert table.read_text() == "mine" and seeds.read_text() == "7\n"


# --- item 19: seeds are int64 ---------------------------------------------------------------

def test_seeds_beyond_int64_are_one_line():
    from panda_lead.seeds import MAX_SEED, parse_seed_range

    assert MAX_SEED == 2**63 - 1 and parse_seed_range(str(MAX_SEED)) == [MAX_SEED]
    for text in (str(2**64), f"{MAX_SEED}-{MAX_SEED + 1}", "9" * 5000):
        with pytest.raises(UserError, match=r"seeds are at most 9223372036854775807") as exc:
            parse_seed_range(text)
        assert len(str(exc.value)) < 200


def test_overlapping_seed_ranges_play_each_seed_once(tmp_path):
    """Regression (issue 21): '0-2,1-3' played and wrote seeds 1 and 2 twice."""
    from panda_lead.seeds import parse_seed_range

    assert parse_seed_range("3-5,0-4") == [3, 4, 5, 0, 1, 2]
    out = run(ROOT / "ikpd.py", "--seeds", "0-1,1-2", "--prefix", "p", "--duration", "0.05",
              cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in (tmp_path / "rollouts" / "p").glob("*.npz")) == [
        "seed_0000.npz", "seed_0001.npz", "seed_0002.npz"]
    assert "wrote 3 rollouts" in out.stdout


@pytest.mark.parametrize("script,args", [
    ("ikpd.py", ["--seeds", str(2**64), "--prefix", "p"]),
    ("ikpd.py", ["--seed", str(2**64), "--video", "v.mp4"]),
    ("trajectory.py", ["--seed", str(2**64)]),
])
def test_a_seed_beyond_int64_is_one_line_through_the_scripts(tmp_path, script, args):
    out = run(ROOT / script, *args, "--duration", "0.1", cwd=tmp_path)
    one_line(out, "2^63-1")
    assert not any(tmp_path.iterdir())


def test_the_largest_seed_runs(tmp_path):
    out = run(ROOT / "ikpd.py", "--seeds", str(2**63 - 1), "--prefix", "p", "--duration",
              "0.1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    (f,) = (tmp_path / "rollouts" / "p").glob("seed_*.npz")
    assert rollout.load(f).seed == 2**63 - 1


# --- item 21: read-only folders ---------------------------------------------------------------

def test_read_only_folders_are_one_line_and_keep_what_is_there(sets, tmp_path):
    with read_only(tmp_path / "ro") as ro:
        one_line(run(ROOT / "trajectory.py", "--seed", "3", "--out", ro / "t.png",
                     cwd=tmp_path), f"cannot write {ro / 't.png'}")
        one_line(metrics(sets, "--plot", ro / "cmp.png", cwd=tmp_path),
                 f"cannot write {ro / 'cmp.png'}")
        one_line(run(ROOT / "ikpd.py", "--seeds", "0", "--prefix", "p", "--rollouts-dir", ro,
                     "--duration", "0.1", cwd=tmp_path), f"cannot write {ro}/p")
        assert not any(ro.iterdir())


# --- item 22: a path of the wrong kind ----------------------------------------------------------

def test_a_path_of_the_wrong_kind_is_one_line(sets, tmp_path):
    folder, a_file = tmp_path / "a_folder", tmp_path / "a_file"
    folder.mkdir()
    a_file.write_text("mine")
    traj = lambda *a: run(ROOT / "trajectory.py", "--seed", "3", *a, cwd=tmp_path)  # noqa: E731
    one_line(traj("--out", folder), "is a folder")
    one_line(traj("--out", folder, "--force"), "is a folder")
    one_line(traj("--out", a_file / "t.png"), "a_file is a file, not a folder")
    one_line(metrics(sets, "--plot", folder, cwd=tmp_path), "is a folder")
    one_line(metrics(sets, "--plot", a_file / "x" / "c.png", cwd=tmp_path),
             "a_file is a file, not a folder")
    one_line(run(ROOT / "metrics.py", "--root", a_file, cwd=tmp_path), "no rollouts under")
    one_line(run(ROOT / "ikpd.py", "--seeds", "0", "--prefix", "p", "--rollouts-dir", a_file,
                 "--duration", "0.1", cwd=tmp_path), "a file is in the way")
    assert a_file.read_text() == "mine" and not any(folder.iterdir())


# --- item 23: absurd sizes (training's are in test_training_faults.py) ----------------------

def test_metrics_bootstrap_and_speed_bins_are_capped(sets, tmp_path):
    out = run(ROOT / "metrics.py", "--root", sets, "--prefix-a", "a", "--prefix-b", "b",
              "--bootstrap", str(10**12), cwd=tmp_path)
    one_line(out, "--bootstrap must be at most 100,000")
    out = run(ROOT / "metrics.py", "--root", sets, "--headline", "a", "b", "--plot",
              tmp_path / "h.png", "--speed-bins", str(10**9), cwd=tmp_path)
    one_line(out, "--speed-bins must be 1..100")
    assert not (tmp_path / "h.png").exists()


def test_an_absurd_duration_is_one_line(tmp_path):
    for script, args in (("ikpd.py", ["--seed", "1", "--video", "v.mp4"]),
                         ("trajectory.py", ["--seed", "1"])):
        out = run(ROOT / script, *args, "--duration", "1e12", cwd=tmp_path)
        one_line(out, "--duration must be a number of seconds in (0, 1000]")
    assert not any(tmp_path.iterdir())


# --- tyro's type errors -------------------------------------------------------------------------

@pytest.mark.parametrize("script,args,words", [
    ("metrics.py", ["--bootstrap", "x"], ["--bootstrap: invalid literal for int()",
                                          "(see metrics.py --help)"]),
    ("metrics.py", ["--boostrap", "5"], ["Unrecognized options: --boostrap",
                                         "did you mean --bootstrap?"]),
    ("trajectory.py", ["--seed", "x"], ["--seed: invalid literal for int()"]),
    ("trajectory.py", ["--duration"], ["Missing value for argument '--duration'"]),
    ("studies/sweep.py", ["--workers", "two"], ["--workers: invalid literal for int()"]),
    ("studies/sweep.py", ["--train-args", "--n-envs 4"], ["--train-args",
                                                         "--train-args=\"--n-envs 4"]),
])
def test_a_command_line_tyro_cannot_parse_is_one_line(tmp_path, script, args, words):
    one_line(run_process(ROOT / script, *args, cwd=tmp_path), *words)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("script,args,words", [
    ("studies/selection.py", ["score", "--models", "archive/nope.zip"], ["model not found"]),
    ("studies/selection.py", ["rnak"], ["rnak"]),
    ("studies/tau.py", ["--taus", "x"], ["--taus"]),
    ("studies/spread.py", ["--bogus"], ["Unrecognized options: --bogus"]),
    ("studies/bench.py", ["--repeats", "x"], ["--repeats: invalid literal for int()"]),
    ("studies/soak.py", ["--bogus"], ["Unrecognized options: --bogus"]),
    ("studies/profile_update.py", ["--variants", "fats"], ["unknown variant 'fats'"]),
    ("studies/online_correction.py", ["play", "--seeds", "0-9"], ["play needs --prefix"]),
    ("studies/online_correction.py", ["play", "--prefix", "x", "--gain", "-1"],
     ["must be finite and >= 0"]),
    ("studies/online_correction.py", ["summary", "--pairs", "a:b", "--names", " ", "x"],
     ["--names needs two non-empty names"]),
    ("studies/online_correction.py", ["play", "--base", "feedforward", "--model",
                                      "archive/x.zip", "--prefix", "x"],
     ["--model is for --base policy", "feedforward"]),
    ("studies/online_correction.py", ["play", "--base", "feedforward", "--oracle", "--prefix",
                                      "x"], ["--oracle", "feedforward base has none"]),
    ("studies/online_correction.py", ["play", "--prefix", "x", "--max-error", "-0.1"],
     ["must be finite and >= 0"]),
    ("studies/online_correction.py", ["excursions", "--groups", "x"],
     ["excursions needs --groups LABEL=PREFIX"]),
    ("studies/online_correction.py", ["play", "--base", "analytic", "--condition", "delay9x",
                                      "--prefix", "x"], ["unknown condition", "delay9x"]),
    ("studies/online_correction.py", ["play", "--base", "analytic", "--condition", "camera1",
                                      "--prefix", "x"], ["camera1", "late target camera"]),
    ("studies/online_correction.py", ["play", "--base", "analytic", "--condition", "delay1",
                                      "--oracle", "--prefix", "x"], ["--oracle", "ideal world"]),
    ("studies/online_correction.py", ["play", "--base", "analytic", "--condition",
                                      "delay3_plan", "--prefix", "x"],
     ["delay3_plan", "only a noise condition"]),
    ("studies/online_correction.py", ["play", "--base", "analytic", "--duration", "-1",
                                      "--prefix", "x"], ["--duration", "positive"]),
    ("studies/online_correction.py", ["tune", "--base", "analytic", "--duration", "10"],
     ["--duration is for play"]),
    ("studies/oracle_share.py", ["--pairs", "x"], ["needs --pairs SET:ORACLE"]),
    ("studies/oracle_share.py", ["--pairs", "x:y", "--root", "."],
     ["no rollouts under analytic/"]),
    ("ikpd.py", ["--controller", "feedforward_plan", "--tau", "0.03", "--seeds", "0-1",
                 "--prefix", "x"], ["--tau does not apply to feedforward_plan"]),
    ("ikpd.py", ["--controller", "classical", "--env.follow-plan", "True",
                 "--env.ik.substep-ik", "True", "--seeds", "0-1", "--prefix", "x"],
     ["follow_plan hands", "substep_ik"]),
])
def test_a_study_scripts_bad_input_is_one_line(tmp_path, script, args, words):
    """The study scripts' entry points go through exit_on_user_error and parse_cli like the
    rest (selection.py printed a ModelError's traceback for a missing model)."""
    one_line(run_process(ROOT / script, *args, cwd=tmp_path), *words)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("script", ["metrics.py", "trajectory.py", "studies/sweep.py"])
def test_help_is_untouched(tmp_path, script):
    out = run(ROOT / script, "--help", cwd=tmp_path)
    assert out.returncode == 0 and out.stderr == ""
    assert "usage:" in out.stdout and "--help" in out.stdout


def test_a_missing_model_is_named_before_the_missing_display(tmp_path, monkeypatch):
    # watching needs a display; the user's missing model is still the first thing they hear
    monkeypatch.setattr("panda_lead.display.has_display", lambda: False)
    one_line(run(ROOT / "eval.py", "--seed", "5", "--model", tmp_path / "nosuch.zip",
                 cwd=tmp_path), "nosuch.zip")


@pytest.mark.parametrize("script,args", [("ikpd.py", ["--seed", "x"]),
                                         ("train.py", ["--n-envs", "x"])])
def test_a_bad_type_in_eval_or_train_is_one_line(tmp_path, script, args):
    one_line(run(ROOT / script, *args, cwd=tmp_path), "invalid literal for int()")


# --- the sweep: items 14, 15, 24 --------------------------------------------------------------

def sweep(*args, cwd):
    return run_process(ROOT / "studies" / "sweep.py", *args, cwd=cwd, timeout=600)


@pytest.mark.slow  # eight sweep.py processes; the default tier checks the sweep's input once
def test_a_sweep_name_is_a_plain_name(tmp_path):
    """--name ../../x wrote sweeps/../../x.db, outside sweeps/."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    for flag in ("--name", "--report", "--archive"):
        one_line(sweep(flag, "../../x", cwd=work), f"{flag} must be a plain name")
    one_line(sweep("--archive", "s", "--archive-as", "/abs", cwd=work),
             "--archive-as must be a plain name")
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


SLOW = pytest.mark.slow  # the same check on more inputs: each case is a sweep.py process


@pytest.mark.parametrize("train_args,words", [
    pytest.param('--n-envs "4', ["No closing quotation"], marks=SLOW),
    ("--n-envs x", ["--n-envs: invalid literal for int()", "(see train.py --help)"]),
    pytest.param("--n-envs 0", ["--n-envs must be an integer >= 1"], marks=SLOW),
    pytest.param("--n-envs 1000000000", ["GiB of memory"], marks=SLOW),
    pytest.param("--env.w-alive -1e308", ["w_alive must be within"], marks=SLOW),
    pytest.param("--env.obs-features ee_pso", ["unknown observation feature"], marks=SLOW),
    ("--timesteps 5", ["may not set --timesteps"]),
    pytest.param("--archive x", ["may not set --archive"], marks=SLOW),
])
def test_sweep_train_args_are_checked_before_the_study_starts(tmp_path, train_args, words):
    """They were parsed only inside a trial: a typo cost a study, a database and a traceback
    per trial."""
    out = sweep("--name", "s", "--presets", "v1", "v5", "--seeds", "1", "2",
                f"--train-args={train_args}", cwd=tmp_path)
    one_line(out, *words)
    assert not any(tmp_path.iterdir())


def test_search_flags_belong_to_the_search(tmp_path):
    one_line(sweep("--name", "s", "--search", "--train-args=--gamma 0.5", cwd=tmp_path),
             "may not set --gamma")
    assert not any(tmp_path.iterdir())


@pytest.mark.slow  # seven sweep.py processes
def test_sweep_storage_failures_are_one_line(tmp_path):
    one_line(sweep("--name", "s", "--storage", "mongodb://localhost/x", cwd=tmp_path),
             "no driver for 'mongodb' databases")
    one_line(sweep("--name", "s", "--heartbeat", "0", cwd=tmp_path),
             "--heartbeat must be at least 1")
    one_line(sweep("--report", "nothing", cwd=tmp_path), "no study named 'nothing'")
    assert not any(tmp_path.iterdir())  # a report of nothing creates no database
    db = tmp_path / "sweeps" / "bad.db"
    db.parent.mkdir()
    db.write_bytes(b"not a database, but the user's file " * 10)
    before = db.read_bytes()
    for args in (["--report", "bad"], ["--name", "bad", "--timesteps", "10"]):
        one_line(sweep(*args, cwd=tmp_path), "cannot open the study storage sqlite:///",
                 "file is not a database")
    assert db.read_bytes() == before and sorted(db.parent.iterdir()) == [db]


def _load_sweep(monkeypatch):
    """studies/sweep.py as a module (studies are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("sweep_under_test",
                                                  ROOT / "studies" / "sweep.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_a_sqlite_study_locked_mid_trial_is_one_line(tmp_path, monkeypatch, capsys):
    """Another connection holds the study's SQLite file locked when a trial reports its
    evaluation. The trial is a stub (the training decides nothing here); the storage, Optuna
    and the sweep's handling are real. SQLite's wait is shortened to 0.5 s for the test (it is
    SQLITE_TIMEOUT_S, 60 s, in use)."""
    import sqlite3

    from panda_lead import training

    sweep_module = _load_sweep(monkeypatch)
    monkeypatch.setattr(sweep_module, "SQLITE_TIMEOUT_S", 0.5)
    monkeypatch.chdir(tmp_path)
    reported = []

    def stub_train(targs, on_eval=None, extra=None):
        lock = sqlite3.connect(tmp_path / "sweeps" / "locked.db", isolation_level=None)
        try:
            lock.execute("BEGIN EXCLUSIVE")  # another process's long write, mid-trial
            reported.append(True)
            on_eval(128, {"mean_error_cm": 5.0})  # trial.report: a write under the lock
        finally:
            lock.execute("ROLLBACK")
            lock.close()
        raise AssertionError("the report under the lock did not fail")

    monkeypatch.setattr(training, "train", stub_train)
    monkeypatch.setattr(sys, "argv", ["sweep.py", "--name", "locked", "--presets", "v5",
                                      "--seeds", "1", "--timesteps", "256", "--eval-freq",
                                      "128"])
    with pytest.raises(SystemExit) as exc:
        sweep_module.main()
    assert exc.value.code == 2 and reported
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: the study storage sqlite:///sweeps/locked.db failed: database is "
                   "locked; finished trials are kept, rerun the same command to continue"]


def test_a_grid_given_new_seeds_is_one_line_not_a_failed_trial(tmp_path, monkeypatch, capsys):
    """queue.sh asked an existing 2-seed study for seeds 1 2 3: Optuna refused the changed
    categorical inside the trial, the sweep caught it as a failed trial and exited 0 having
    trained nothing. The training is a stub; the storage, Optuna and the check are real."""
    from panda_lead import training

    sweep_module = _load_sweep(monkeypatch)
    monkeypatch.chdir(tmp_path)
    trained = []

    def stub_train(targs, on_eval=None, extra=None):
        run_dir = tmp_path / f"run{len(trained)}"
        run_dir.mkdir()
        (run_dir / "best.json").write_text('{"mean_error_cm": 3.0}')
        trained.append(targs.seed)
        return run_dir

    monkeypatch.setattr(training, "train", stub_train)
    argv = ["sweep.py", "--name", "g", "--presets", "v5", "--timesteps", "256", "--seeds"]
    monkeypatch.setattr(sys, "argv", argv + ["1", "2"])
    sweep_module.main()
    assert sorted(trained) == [1, 2]
    capsys.readouterr()
    monkeypatch.setattr(sys, "argv", argv + ["1", "2", "3"])
    with pytest.raises(SystemExit) as exc:
        sweep_module.main()
    assert exc.value.code == 2 and sorted(trained) == [1, 2]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a grid over seed [1, 2], not [1, 2, 3]" in err[0]


def test_an_unknown_queue_is_one_line_and_trains_nothing(tmp_path):
    """queue.sh's last branch used to be the 1M side studies, so a misspelt queue name
    (`bash studies/queue.sh headline_5`) started eight 1M-step grids."""
    result = subprocess.run(["bash", str(ROOT / "studies" / "queue.sh"), "headline_5"],
                            capture_output=True, text=True, timeout=60, env=ENV)
    assert result.stdout == ""
    one_line(result, "no queue 'headline_5'", "headline5")
    assert not (ROOT / "sweeps" / "headline_5").exists()


def test_a_reader_that_stops_reading_ends_the_command_quietly(tmp_path):
    """`uv run studies/runs.py rank | head -1`: the reader closes the pipe, the next write
    fails with EPIPE. The command stops with 141 (128 + SIGPIPE) and no traceback. The pipe's
    read end is closed before the command starts, so its first write fails, whatever the
    machine's speed."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, str(ROOT / "studies" / "runs.py"), "rank"],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                              timeout=600)
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr
