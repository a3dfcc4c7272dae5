"""train.py: the typed config and presets, signals, resume, the run's talk, TensorBoard, the
model card. Training runs are tiny (a few hundred steps, 2 envs); the archived run is the
session's shared one (conftest.tiny_run); train.py runs as a process only where the process is
the point (signals, a real exit status), in-process through its main function elsewhere."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import PipeLines, main_exit

from panda_lead.cli.train import main as train_main
from panda_lead.cli.train import parse_args
from panda_lead.config import EnvConfig
from panda_lead.errors import UserError
from panda_lead.training import PRESETS, TrainConfig
from panda_lead.training.loop import check_device

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
        "--n-workers", "1", "--no-progress"]


def run(*args, cwd, timeout=600):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, "MUJOCO_GL": "egl"})


# --- the typed config --------------------------------------------------------------------------

def test_an_explicit_flag_wins_over_the_preset_even_at_its_default():
    # The old bug: `--preset v4 --ent-coef 0.0` trained with v4's 0.01 (0.0 was the default).
    args = parse_args(["--preset", "v4", "--ent-coef", "0.0"])
    assert args.ent_coef == 0.0
    assert args.env == PRESETS["v4"].env and args.preset == "v4"
    assert parse_args(["--preset", "v4"]).ent_coef == 0.01
    # Flags before --preset win too; nested env flags override the preset's env field by field.
    args = parse_args(["--env.max-lead", "0.1", "--preset", "v9", "--env.obs-noise",
                       "target_vel", "0.05"])
    assert args.env.max_lead == 0.1 and args.env.w_action_change == 0.1
    assert args.env.obs_noise == {"target_vel": 0.05} and args.env.episode_steps == 500
    args = parse_args(["--env.obs-features", "target_vel", "ee_pos"])
    assert args.env.obs_features == ("ee_pos", "target_vel")  # canonical order


def test_reference_hparams_is_a_starting_point_that_flags_override():
    args = parse_args(["--reference-hparams", "--n-envs", "4"])
    assert (args.n_envs, args.n_steps, args.learning_rate) == (4, 1024, 3e-4)


def test_a_cuda_device_picks_the_gpu_profile_and_flags_still_override(tmp_path):
    from panda_lead.training.config import PROFILES

    gpu, default = PROFILES["gpu"], parse_args([])
    assert default.profile == "cpu" and (default.n_envs, default.device) == (32, "cpu")
    for argv in (["--device", "cuda"], ["--profile", "gpu"], ["--device=cuda:0", "--preset", "v5"]):
        args = parse_args(argv)
        assert args.profile == "gpu"
        assert (args.n_envs, args.batch_size) == (gpu["n_envs"], gpu["batch_size"]) != (32, 1024)
    assert parse_args(["--device=cuda:0"]).device == "cuda:0"
    assert parse_args(["--device", "cuda", "--n-envs", "64"]).n_envs == 64
    kept = parse_args(["--device", "cuda", "--profile", "cpu"])
    assert (kept.profile, kept.device, kept.n_envs, kept.batch_size) == ("cpu", "cuda", 32, 1024)
    with pytest.raises(UserError, match="--profile must be one of"):
        parse_args(["--profile", "tpu"])
    with pytest.raises(UserError, match="--profile changes what a run learns"):
        parse_args(["--resume", str(tmp_path), "--profile", "gpu"])


@pytest.mark.parametrize("study, preset", [("err_delayed", "err_delayed"),
                                           ("v5_err_decay_wide_lr3e-4", "v5_err_decay_wide_slow")])
def test_a_preset_names_exactly_what_a_flag_trained_study_ran(study, preset):
    # These studies were trained as a preset plus flags (`--train-args`); their committed
    # summaries carry the whole config, and the preset named after them must reproduce it.
    for f in sorted((ROOT / "results" / "runs" / study).glob("seed_*.json")):
        trained = json.loads(f.read_text())["train_config"]
        named = PRESETS[preset].to_dict()
        for key in ("seed", "preset"):
            trained.pop(key), named.pop(key)
        # Summaries from before fast_update ran SB3's PPO, whose update FastPPO repeats bit
        # for bit (tests/test_fast_ppo.py): the field does not change what a run learns.
        if "fast_update" not in trained:
            named.pop("fast_update")
        # A training field a summary lacks was added after its run (the CAPS weights, issue
        # 36): the run trained at the field's default, which the preset must hold too.
        train_defaults = TrainConfig().to_dict()
        for key in set(named) - set(trained):
            assert named.pop(key) == train_defaults[key], (f.name, key)
        # An env field a summary lacks was added after its run (preview_times, issue 37): the
        # run behaved as the field's default, so the preset must hold that default there.
        defaults = EnvConfig().to_dict()
        for key in set(named["env"]) - set(trained["env"]):
            assert named["env"].pop(key) == defaults[key], (f.name, key)
        assert trained == named, f.name


def test_a_card_names_what_the_runs_flags_changed_from_its_preset():
    from panda_lead.training.archive import _changed_from_preset

    as_named = PRESETS["v5_err_decay_wide"].to_dict()
    assert _changed_from_preset({**as_named, "seed": 3, "timesteps": 1000}) == ""
    flagged = parse_args(["--preset", "v5_err_decay_wide", "--learning-rate", "3e-4",
                          "--env.obs-delay", "2"]).to_dict()
    assert _changed_from_preset(flagged) == (" with learning_rate 0.0003 (the preset: 0.001), "
                                             "env.obs_delay 2 (the preset: 0)")


def test_preset_help_shows_the_presets_values_and_no_internal_flags(tmp_path, monkeypatch,
                                                                    capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("COLUMNS", "100")  # the help's width, whatever the terminal
    code, stdout, err = main_exit(train_main, ["--preset", "v4", "--help"], capsys)
    assert code == 0, err
    text = re.sub(r"[│\s]+", " ", stdout)
    assert "Train a PPO lead policy" in text  # the module description
    assert "--ent-coef FLOAT Entropy bonus coefficient. (default: 0.01)" in text
    assert "(default: ee_pos ee_vel target_pos target_vel)" in text  # v4's 12-D features
    assert "smooth" in text and "--env.obs-noise" in text
    assert "--extra" not in text and "--env-kwargs" not in text
    assert not any(tmp_path.iterdir())


def test_config_round_trips_and_reads_the_old_layout():
    cfg = PRESETS["smooth"]
    assert TrainConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    old = {"preset": "v4", "ppo": {"ent_coef": 0.01, "n_steps": 128}, "net_arch": [64, 64],
           "env": {"obs_features": ["ee_pos"]},
           "env_resolved": EnvConfig(obs_features=("ee_pos", "ee_vel")).to_dict(),
           "n_envs": 32, "timesteps": 1000, "extra": {"trial": 3}}
    got = TrainConfig.from_dict(old)
    assert got.ent_coef == 0.01 and got.env.obs_features == ("ee_pos", "ee_vel")


@pytest.mark.parametrize("argv,message", [
    (["--timesteps", "0"], "--timesteps must be an integer >= 1"),
    (["--timesteps", "-5"], "--timesteps must be an integer >= 1"),
    (["--n-envs", "0"], "--n-envs must be an integer >= 1"),
    (["--batch-size", "1"], "--batch-size must be an integer >= 2"),
    (["--torch-threads", "0"], "--torch-threads must be an integer >= 1"),
    (["--gamma", "nan"], "--gamma must be a finite number"),
    (["--env.ik.iters", "0"], "ik.iters must be in [1, 100]"),
    (["--env.tracking-scale", "0"], "tracking_scale must be > 0"),
    (["--env.obs-noise", "target_vel", "nan"], "must be a finite std"),
    (["--env.obs-noise", "targt_vel", "0.1"], "did you mean 'target_vel'"),
    (["--env.obs-features", "ee_pso"], "unknown observation feature"),
    (["--preset", "v55"], "did you mean 'v5'"),
    (["--archive", "../x"], "--archive must be a plain name"),
    (["--resume", "nowhere"], "not a run folder"),
])
def test_bad_training_input_is_a_user_error(argv, message):
    with pytest.raises(UserError, match=re.escape(message)):
        parse_args(argv)


def test_bad_training_input_exits_2_with_one_line(tmp_path):
    out = run(ROOT / "train.py", "--timesteps", "0", "--runs-dir", tmp_path / "runs", cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0
    assert out.stderr.startswith("error: --timesteps") and not (tmp_path / "runs").exists()


# --- a tiny run, archived ----------------------------------------------------------------------

@pytest.fixture
def archived(tiny_run):
    """The shared tiny run (200 steps asked, evaluations every 128; resumed and archived as
    archive/tiny): its work folder, run folder and the first run's output."""
    tmp, run_dir, first, _ = tiny_run
    return tmp, run_dir, first


def test_training_talks(archived):
    tmp, run_dir, out = archived
    lines = out.stdout.splitlines()
    assert lines[0] == f"run folder: {run_dir}"
    # 200 asked, whole rollouts of 64 x 2: the run says it ends at 256.
    assert "so this run ends at 256 steps (asked: 200)" in out.stdout
    evals = [x for x in lines if x.startswith("step ")]
    assert len(evals) == 2 and all("in 5 cm band" in x and "classical" in x and "analytic" in x
                                   for x in evals)
    assert "best evaluation error" in out.stdout and "best_model.zip" in out.stdout
    assert "uv run eval.py --seeds 0-99" in out.stdout and "uv run metrics.py" in out.stdout
    config = json.loads((run_dir / "config.json").read_text())
    assert TrainConfig.from_dict(config).n_envs == 2 and config["env"]["max_lead"] == 0.15


def test_tensorboard_has_baselines_at_every_evaluation_and_one_chart(archived):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    _, run_dir, _ = archived
    acc = EventAccumulator(str(run_dir / "tb")).Reload()
    tags = acc.Tags()["scalars"]
    policy = [e.step for e in acc.Scalars("eval/mean_error_cm")]
    for name in ("eval_classical/mean_error_cm", "eval_analytic/mean_error_cm"):
        assert name in tags and [e.step for e in acc.Scalars(name)] == policy
    assert "custom_scalars__config__" in acc.PluginTagToContent("custom_scalars")
    layout = acc.Tensors("custom_scalars__config__")[0].tensor_proto.string_val[0]
    assert b"eval/mean_error_cm" in layout and b"eval_analytic/mean_error_cm" in layout


def test_archive_refuses_to_overwrite_without_force(tiny_run_copy, monkeypatch, capsys):
    tmp, run_dir, _, _ = tiny_run_copy  # a copy: a regression would overwrite its archive
    before = (tmp / "archive" / "tiny.zip").read_bytes()
    monkeypatch.chdir(tmp)
    code, _, err = main_exit(train_main, ["--archive", "tiny", "--timesteps", "10"], capsys)
    assert code == 2 and "archive/tiny.zip exists" in err and "--force" in err
    assert (tmp / "archive" / "tiny.zip").read_bytes() == before
    from panda_lead import training

    with pytest.raises(UserError, match="exists"):
        training.archive_model(run_dir, "tiny")
    assert (tmp / "archive" / "tiny.zip").read_bytes() == before


def test_model_card_snippet_reproduces_the_rollout(tiny_run_copy, monkeypatch, capsys):
    import runpy

    from panda_lead.cli.main import eval_command

    tmp, _, _, _ = tiny_run_copy  # a copy: the snippet and eval.py write into the folder
    monkeypatch.chdir(tmp)
    card = (tmp / "archive" / "tiny.md").read_text()
    side = json.loads((tmp / "archive" / "tiny.json").read_text())
    assert "PPO.load" in card and "weights_only" in card and side["model_sha256"][:12]
    snippet = re.search(r"```python\n(.*?)```", card, re.S).group(1)
    assert len(snippet.splitlines()) <= 20
    (tmp / "snippet.py").write_text(snippet)
    capsys.readouterr()
    runpy.run_path(str(tmp / "snippet.py"), run_name="__main__")  # as `python snippet.py`
    printed = float(re.search(r"mean error ([\d.]+) cm", capsys.readouterr().out).group(1))
    # The same number as the card and as eval.py's rollout file of test seed 0.
    assert f"{printed:.6f}" == f"{side['test_seed0_mean_error_cm']:.6f}"
    code, _, err = main_exit(eval_command, ["--seeds", "0", "--prefix", "card", "--model",
                                            "archive/tiny.zip"], capsys)
    assert code == 0, err
    from panda_lead.rollout import load

    r = load(tmp / "rollouts" / "card" / "seed_0000.npz")
    assert f"{100 * r.error.mean():.6f}" == f"{printed:.6f}"


# --- signals and resume ------------------------------------------------------------------------

@pytest.mark.parametrize("sig,code", [
    (signal.SIGTERM, 143),
    # slow tier: the default one sends SIGINT during the final evaluation
    # (test_training_faults) and checks its exit status 130, save and resume line there
    pytest.param(signal.SIGINT, 130, marks=pytest.mark.slow)])
def test_a_signal_to_the_main_process_alone_saves_and_resume_appends(tmp_path, monkeypatch,
                                                                     capsys, sig, code):
    cmd = [sys.executable, str(ROOT / "train.py"), "--timesteps", "1000000", "--eval-freq", "0",
           "--checkpoint-freq", "128", "--runs-dir", str(tmp_path / "runs"), *TINY]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env={**os.environ, "MUJOCO_GL": "egl"})
    out_lines, err_lines = PipeLines(proc.stdout), PipeLines(proc.stderr)
    try:
        out_lines.wait_for("training started")
        run_dir = next((tmp_path / "runs").iterdir())
        csv = run_dir / "tb" / "progress.csv"
        logged = lambda: csv.is_file() and len(csv.read_text().splitlines()) >= 3  # noqa: E731
        deadline = time.monotonic() + 600  # a hang guard, not a time budget
        while time.monotonic() < deadline and not logged():
            time.sleep(0.1)  # polling for the event: a couple of PPO iterations logged
        assert logged(), "no PPO iteration logged"
        os.kill(proc.pid, sig)  # the main process only, not its group
        proc.wait(timeout=600)  # a hang guard: it saves and exits within seconds
        out, err = out_lines.text(), err_lines.text()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == code, err
    assert f"resume with: uv run train.py --resume {run_dir}" in out
    side = json.loads((run_dir / "interrupted_model.json").read_text())
    rows_before = len(csv.read_text().splitlines())
    if sig == signal.SIGINT:
        return  # one resume below is enough
    # Truncate the newest save: resume must skip it and fall back to the newest valid one.
    interrupted = run_dir / "interrupted_model.zip"
    interrupted.write_bytes(interrupted.read_bytes()[:300])
    ckpts = {int(json.loads(p.read_text())["timesteps"]): p
             for p in (run_dir / "checkpoints").glob("*.json")}
    fallback = max(ckpts)
    assert fallback <= side["timesteps"]
    monkeypatch.chdir(tmp_path)
    status, stdout, stderr = main_exit(train_main, ["--resume", run_dir, "--timesteps",
                                                    fallback + 128, "--no-progress"], capsys)
    assert status == 0, stderr
    assert "skipping" in stderr and "interrupted_model.zip" in stderr
    assert f"from {ckpts[fallback].stem}.zip at {fallback} steps" in stdout
    final = json.loads((run_dir / "final_model.json").read_text())
    assert final["timesteps"] == fallback + 128
    assert len(csv.read_text().splitlines()) > rows_before  # appended, not cut
    # Regression (issue 21): the wall time counted only the resumed part (a module-level clock
    # reset on resume); it carries on from the checkpoint's.
    before = json.loads(ckpts[fallback].read_text())["wall_time_s"]
    assert final["wall_time_s"] >= before > 0


def test_resume_refuses_to_change_what_the_run_learns(tmp_path):
    run_dir = tmp_path / "r"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(PRESETS["v5"].to_dict()))
    with pytest.raises(UserError, match="--n-envs cannot change"):
        parse_args(["--resume", str(run_dir), "--n-envs", "3"])
    assert parse_args(["--resume", str(run_dir), "--timesteps", "7"]).timesteps == 7


def test_a_joint_residual_run_trains_and_evaluates_against_both_baselines(tmp_path, capsys):
    """The analytic baseline of a joint-residual run is the Cartesian lead on the same task."""
    from panda_lead.training import train

    capsys.readouterr()
    train(parse_args(["--preset", "joint", "--timesteps", "256", "--eval-freq", "128",
                      "--runs-dir", str(tmp_path), *TINY]))
    stdout = capsys.readouterr().out
    from panda_lead.config import EnvConfig
    from panda_lead.controllers import make_analytic
    from panda_lead.training import evaluate

    lead_task = EnvConfig(obs_features=("ee_pos", "ee_vel", "target_pos", "target_vel",
                                        "target_acc"))  # the joint preset's task, lead action
    expected = evaluate(make_analytic(), lead_task, 500)["mean_error_cm"]
    assert f"analytic {expected:.2f} cm" in stdout  # the lead baseline on the same task
    (run,) = tmp_path.glob("joint__*")
    from panda_lead.models import load_policy

    policy, env_config, _ = load_policy(run / "best_model.zip")  # a 7-D action loads safely
    assert policy.action_space.shape == (7,) and env_config["action"] == "joint"


def test_a_residual_run_compares_with_the_plain_baselines_and_its_rival(tmp_path, capsys):
    """On a feedforward env a zero lead IS the feedforward rival: the run's classical and
    analytic lines play without it (as eval.py's baselines do), the rival is its own line."""
    from panda_lead.training import train

    capsys.readouterr()
    train(parse_args(["--preset", "preview_feedforward", "--timesteps", "128", "--eval-freq",
                      "128", "--runs-dir", str(tmp_path), *TINY]))
    stdout = capsys.readouterr().out
    from panda_lead.controllers import classical, make_analytic
    from panda_lead.training import evaluate, get_preset

    env = get_preset("preview_feedforward").env
    plain = env.replace(feedforward=False)
    expected = {"classical": evaluate(classical, plain, 500)["mean_error_cm"],
                "analytic": evaluate(make_analytic(), plain, 500)["mean_error_cm"],
                "feedforward": evaluate(classical, env, 500)["mean_error_cm"]}
    assert expected["feedforward"] < expected["analytic"] < expected["classical"]
    (line,) = [x for x in stdout.splitlines() if x.startswith("step ")]
    for name, cm in expected.items():
        assert f"{name} {cm:.2f} cm" in line


def test_a_cuda_device_that_is_not_there_is_a_clear_error():
    import torch


    class Torch:  # torch, with or without a GPU
        device = staticmethod(torch.device)

        def __init__(self, gpu):
            self.cuda = type("cuda", (), {"is_available": staticmethod(lambda: gpu)})

    with pytest.raises(UserError, match="no CUDA GPU"):
        check_device("cuda", Torch(gpu=False))
    with pytest.raises(UserError, match="not a torch device"):
        check_device("gpu0", Torch(gpu=True))
    check_device("cuda:0", Torch(gpu=True))
    check_device("cpu", Torch(gpu=False))


def _drawn_trajectory_seeds(kind: str, seed: int, n_envs: int = 3, episodes: int = 2):
    """Per env, the trajectory seeds it plays, episode by episode, when training makes the vec
    env and PPO seeds it (SB3 calls env.seed(seed) in PPO's constructor)."""
    from stable_baselines3 import PPO

    from panda_lead.training.envs import make_vec_env

    vec = make_vec_env(EnvConfig(episode_steps=2), n_envs, seed, kind, n_workers=1)
    PPO("MlpPolicy", vec, seed=seed, n_steps=64, device="cpu")

    def current() -> list[int]:
        if kind == "batched":
            return [int(s) for s in vec.task.traj_seeds]
        return [int(e.unwrapped.task.traj_seeds[0]) for e in vec.venv.venv.envs]  # dummy

    vec.reset()
    drawn = []
    for _ in range(episodes):
        drawn.append(current())
        for _ in range(2):  # episode_steps=2: the second step autoresets every env
            vec.step(np.zeros((n_envs, 3), np.float32))
    vec.close()
    return [list(col) for col in zip(*drawn, strict=True)]


@pytest.mark.parametrize("kind", ["dummy", "batched"])
def test_training_seeds_draw_disjoint_streams_whatever_the_vec_env(kind):
    """Regression (issue 21): with --vec-env dummy/subproc, PPO reseeded env i with seed + i,
    so training seeds s and s+1 shared n-1 of their n trajectory streams."""
    a, b = _drawn_trajectory_seeds(kind, 5), _drawn_trajectory_seeds(kind, 6)
    flat_a, flat_b = {x for row in a for x in row}, {x for row in b for x in row}
    assert len(flat_a) == 6 and not flat_a & flat_b
    if kind == "dummy":  # and the same streams as the batched env (one rule for all)
        assert a == _drawn_trajectory_seeds("batched", 5)


def test_the_loop_raises_training_interrupted_after_saving(tmp_path):
    """Regression (issue 21): training.train() raised SystemExit itself, which a library caller
    (a sweep, a notebook) could not tell from a real exit. It saves, then raises an exception
    of its own; train.py turns that into exit status 128 + the signal."""
    from panda_lead.training import TrainingInterrupted, train

    args = parse_args(["--timesteps", "1024", "--eval-freq", "128", "--runs-dir",
                       str(tmp_path / "runs"), *TINY])

    def ctrl_c(step, metrics):
        raise KeyboardInterrupt

    with pytest.raises(TrainingInterrupted) as info:
        train(args, on_eval=ctrl_c)
    assert info.value.signum == signal.SIGINT
    assert (info.value.run_dir / "interrupted_model.zip").is_file()


def test_target_kl_stops_an_updates_epochs_early(tmp_path):
    """--target-kl reaches SB3's PPO: with a bound no update can stay under, each update stops
    in its first epoch; without one all 4 epochs run."""
    import csv

    from panda_lead.training import train

    def updates(*flags):
        args = parse_args(["--timesteps", "512", "--eval-freq", "0", "--runs-dir",
                           str(tmp_path / f"runs{len(flags)}"), *TINY, "--n-epochs", "4",
                           "--learning-rate", "0.01", *flags])
        run_dir = train(args)
        rows = list(csv.DictReader(open(run_dir / "tb" / "progress.csv")))
        return [int(float(r["train/n_updates"])) for r in rows if r.get("train/n_updates")]

    # 4 rollouts of 128 steps; SB3 writes an update's counters with the next rollout's line,
    # so the log holds the first 3 updates. n_updates counts epochs begun.
    assert updates() == [4, 8, 12]
    assert updates("--target-kl", "1e-12") == [1, 2, 3]
    assert parse_args(["--preset", "ikfree_err_kl"]).target_kl == 0.02
    with pytest.raises(UserError, match="--target-kl"):
        TrainConfig(target_kl=0.0)


def test_a_model_names_the_commit_its_process_imported_not_the_tree_at_save_time(
        tmp_path, monkeypatch):
    """A sweep's trials (or a save after someone edits the tree) ran the code imported at the
    start, but the sidecar read git at each save: it could name a commit or a clean tree the
    weights were not trained with."""
    from panda_lead import models
    from panda_lead.training import loop, train

    monkeypatch.setattr(models, "git_commit", lambda: "a-later-tree")  # the tree moves on
    args = parse_args(["--timesteps", "256", "--eval-freq", "128", "--runs-dir",
                       str(tmp_path / "runs"), *TINY])
    run_dir = train(args)
    for name in ("best_model.zip", "final_model.zip"):
        assert models.verify(run_dir / name)["commit"] == loop.CODE_COMMIT != "a-later-tree"
