"""Reliability round 4 (docs/reliability.md, "Round 4: files, resume, adopt"): what a rollout
file, a run folder, an archive name and an adopted model may hold, each defect of
../shared/RELIABILITY-4.md (and issue 38's review) reproduced in-process on files the repo's
own writers made in tmp_path."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from panda_lead import rollout
from panda_lead.errors import UserError
from panda_lead.rollout import RolloutError

STEPS = 50  # 0.5 s episodes: every check below is about the file, not the length


@pytest.fixture(scope="module")
def played():
    """Seeds 0-3 of the classical controller, 0.5 s each, played by the repo's harness."""
    from panda_lead import harness

    ctrl = harness.build("classical", STEPS)
    return list(rollout.iter_record(ctrl.config, ctrl.act, [0, 1, 2, 3], None, ctrl.meta))


def write_set(root: Path, prefix: str, rollouts) -> Path:
    for r in rollouts:
        rollout.save(r, rollout.rollout_path(prefix, r.seed, root))
    return root / prefix


def keys(r: rollout.Rollout) -> list[str]:
    """The arrays a rollout holds (the optional ones where present)."""
    return [k for k in (*rollout.ARRAY_KEYS, *rollout.OPTIONAL_KEYS) if getattr(r, k) is not None]


def copy(r: rollout.Rollout) -> rollout.Rollout:
    return dataclasses.replace(r, **{k: np.array(getattr(r, k)) for k in keys(r)},
                               meta=dict(r.meta))


# --- the rollout format checks its invariants on read (#7-#10) ------------------------------

def test_an_untouched_set_loads(played, tmp_path):
    write_set(tmp_path, "base", played)
    loaded = rollout.load_prefix("base", tmp_path)
    assert sorted(loaded) == [0, 1, 2, 3]
    assert np.array_equal(loaded[2].ee_pos, played[2].ee_pos)


def test_rows_beyond_the_meta_duration_are_refused(played, tmp_path):
    """#7: a file with twice the rows its meta's duration allows (the second half 20 cm off)
    used to be scored over all of them."""
    r = copy(played[1])
    for k in keys(r):
        a = getattr(r, k)
        setattr(r, k, np.concatenate([a, a]))
    r.t = 0.01 * np.arange(1, 2 * STEPS + 1)
    r.ee_pos[STEPS:] += [0.2, 0, 0]
    path = rollout.save(r, tmp_path / "seed_0001.npz")
    with pytest.raises(RolloutError, match=f"{2 * STEPS} rows, but its meta says 0.5 s at "
                                           f"0.01 s = {STEPS} steps"):
        rollout.load(path)


@pytest.mark.parametrize("value", [0.0, -0.3, 0.125])
def test_a_time_off_the_meta_step_is_refused(played, tmp_path, value):
    """#7: a zero or negative t made one seed's settled error NaN and dropped it from one set."""
    r = copy(played[0])
    r.t[10] = value
    path = rollout.save(r, tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError, match="t is .* s at step 10, but step 10 of its meta's"):
        rollout.load(path)


def test_an_episode_that_ended_early_still_loads(played, tmp_path):
    """Fewer rows than the duration is a failed episode: it loads, and metrics charges it."""
    r = copy(played[0])
    for k in keys(r):
        setattr(r, k, getattr(r, k)[:20])
    r.meta["failure"] = "unstable"
    r.t[-1] = 0.0  # MuJoCo resets an unstable simulation's clock: the last row is not checked
    assert len(rollout.load(rollout.save(r, tmp_path / "seed_0000.npz")).t) == 20


def test_another_seeds_episode_under_this_seed_is_refused(played, tmp_path):
    """#8: seed 3's episode relabelled seed 2 (same shape or not) was paired with seed 2."""
    r = copy(played[3])
    r.meta["seed"] = 2
    path = rollout.save(r, tmp_path / "seed_0002.npz")
    with pytest.raises(RolloutError, match="target_pos at step 0 is not seed 2's"):
        rollout.load(path)


@pytest.mark.parametrize("key", ["target_pos", "target_vel", "target_acc"])
def test_an_edited_target_is_refused(played, tmp_path, key):
    """#8: target_pos := ee_pos scored 0 error."""
    r = copy(played[1])
    if key == "target_pos":
        r.target_pos = r.ee_pos.copy()
    else:
        getattr(r, key)[30, 2] += 0.5
    path = rollout.save(r, tmp_path / "seed_0001.npz")
    with pytest.raises(RolloutError, match=f"{key} at step .* is not seed 1's"):
        rollout.load(path)


def test_two_files_claiming_one_seed_are_refused(played, tmp_path):
    """#9: seed_0011.npz holding seed 3 + 5 cm silently replaced seed 3 (or was dropped)."""
    folder = write_set(tmp_path, "dup", played)
    r = copy(played[3])
    r.ee_pos += [0.05, 0, 0]
    rollout.save(r, folder / "seed_0011.npz")
    with pytest.raises(RolloutError, match="seed_0011.npz: .*its meta says seed 3, so it "
                                           "should be named seed_0003.npz"):
        rollout.load_prefix("dup", tmp_path)
    from panda_lead.metrics import load_set

    with pytest.raises(UserError, match="seed_0011"):
        load_set("dup", tmp_path)


@pytest.mark.parametrize("key,dtype,words", [
    ("ee_pos", np.int64, "ee_pos has dtype int64, expected numbers"),
    ("t", np.int32, "t has dtype int32, expected numbers"),
    ("self_collision", np.int64, "self_collision has dtype int64, expected bool"),
    ("reachable", np.uint8, "reachable has dtype uint8, expected bool"),
])
def test_integer_arrays_are_refused(played, tmp_path, key, dtype, words):
    """#10: ee_pos as int64 (+5.72 cm on one seed), self_collision = 7 (700% of the time)."""
    r = copy(played[0])
    setattr(r, key, (getattr(r, key) * (7 if key == "self_collision" else 1)).astype(dtype))
    path = rollout.save(r, tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError, match=words):
        rollout.load(path)


def test_load_set_keeps_the_traceback_of_a_bug(monkeypatch, tmp_path, played):
    """Issue 38: load_set turned any ValueError into a user error, hiding real bugs."""
    from panda_lead.metrics import load_set

    write_set(tmp_path, "base", played)

    def broken(path):
        raise ValueError("a bug in the reader")

    monkeypatch.setattr(rollout, "load", broken)
    with pytest.raises(ValueError, match="a bug in the reader"):
        load_set("base", tmp_path)
    monkeypatch.undo()
    with pytest.raises(UserError, match="no rollouts under"):
        load_set("nothing", tmp_path)


# --- archive names, locks, models (#1, #26, #27, #28, #17) -----------------------------------

def test_an_archive_name_whose_card_alone_exists_is_refused(tmp_path, monkeypatch):
    """#1: `--archive mycard` replaced archive/mycard.md when no mycard.zip/.json existed."""
    from panda_lead.training.archive import check_archive_free

    monkeypatch.chdir(tmp_path)
    (tmp_path / "archive").mkdir()
    (tmp_path / "archive" / "mycard.md").write_text("my notes\n")
    with pytest.raises(UserError, match=r"archive/mycard.md exists .*add --force"):
        check_archive_free("mycard", force=False)
    check_archive_free("mycard", force=True)
    check_archive_free("free_name", force=False)
    assert (tmp_path / "archive" / "mycard.md").read_text() == "my notes\n"


def test_a_full_disk_while_taking_a_lock_is_one_line(tmp_path, monkeypatch):
    """#26: file_lock wrote and flushed its pid without user_error_for: an OSError traceback."""
    import errno
    import os

    from panda_lead import atomicio

    class FullDisk:
        def __init__(self, f):
            self.f = f

        def __getattr__(self, name):
            return getattr(self.f, name)

        def write(self, text):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    real_open = open
    monkeypatch.setattr(atomicio, "open", lambda *a, **k: FullDisk(real_open(*a, **k)),
                        raising=False)
    with pytest.raises(UserError, match=r"cannot write .*\.lock: No space left on device"):
        with atomicio.file_lock(tmp_path / "p" / ".lock", "the rollout set"):
            pass


def _poison_first_weight(raw: bytes) -> bytes:
    import io

    import torch

    state = torch.load(io.BytesIO(raw), weights_only=True)
    state["action_net.weight"][0, 0] = float("nan")
    out = io.BytesIO()
    torch.save(state, out)
    return out.getvalue()


def test_a_bound_model_with_nan_weights_is_refused_on_load(tmp_path):
    """#28: NaN weights passed load_policy and failed mid-episode ('action must be finite')."""
    from stable_baselines3 import PPO
    from test_adopt import Spaces, edit_member

    from panda_lead import models
    from panda_lead.config import EnvConfig

    obs_space, _ = models.spaces_for(EnvConfig())
    ppo = PPO("MlpPolicy", Spaces(obs_space.shape[0]), n_steps=64, batch_size=64, device="cpu")
    path = models.save_model(ppo, tmp_path / "m.zip",
                             {"env_config": EnvConfig().to_dict(), "timesteps": 0})
    models.load_policy(path)  # as saved: loads
    edit_member(path, "policy.pth", _poison_first_weight)
    models.bind_sidecar(path)  # the hash made to match, as a careless hand would
    with pytest.raises(models.ModelError, match="action_net.weight holds NaN or infinite"):
        models.load_policy(path)


def test_the_observation_size_hint_knows_stacked_features(tmp_path):
    """Issue 38: the observation-size hint was written twice (models, adopt), and the model
    loader's copy did not know stacked observations. One definition: models.obs_flags_for."""
    from test_adopt import save_ppo

    from panda_lead import models
    from panda_lead.config import OBS_15

    path = save_ppo(tmp_path / "stacked.zip", obs_dim=30)  # OBS_15 x 2, no sidecar
    with pytest.raises(models.ModelError,
                       match=f"--env.obs-features {' '.join(OBS_15)} --env.obs-stack 2"):
        models.read_sidecar(path)


def _edit_state(key_edit):
    def edit(raw: bytes) -> bytes:
        import io

        import torch

        state = torch.load(io.BytesIO(raw), weights_only=True)
        key_edit(state)
        out = io.BytesIO()
        torch.save(state, out)
        return out.getvalue()
    return edit


@pytest.mark.parametrize("case,match", [
    ("extra_key", "mlp_extractor.policy_net.abc.weight .* no layer of an SB3 MLP"),
    ("flat_first_layer", r"mlp_extractor.policy_net.0.weight of shape \(960,\)"),
    ("deep_data", "nests too deeply"),
])
def test_odd_weights_or_data_are_refused_by_adopt(tmp_path, case, match):
    """#27: an extra weight key (ValueError), a 1-D first layer (IndexError), deeply nested
    data (RecursionError) were tracebacks."""
    from test_adopt import edit_member, refused, save_ppo

    path = save_ppo(tmp_path / f"{case}.zip")
    if case == "extra_key":
        edit_member(path, "policy.pth", _edit_state(lambda s: s.__setitem__(
            "mlp_extractor.policy_net.abc.weight", s["mlp_extractor.policy_net.0.weight"])))
    elif case == "flat_first_layer":
        edit_member(path, "policy.pth", _edit_state(lambda s: s.__setitem__(
            "mlp_extractor.policy_net.0.weight",
            s["mlp_extractor.policy_net.0.weight"].reshape(-1))))
    else:
        edit_member(path, "data", lambda raw: raw[:-1] + b', "x": ' + b"[" * 100_000
                    + b"]" * 100_000 + b"}")
    refused(path, match)


def test_an_rl_zoo_alias_bomb_is_refused_before_it_expands(tmp_path):
    """#17: SafeLoader expanded aliases, then formatted the value into the error (a 535-byte
    file: MemoryError at a 4 GB cap). Six levels of ten here: a million values if expanded."""
    from test_adopt import refused, save_ppo, zoo_yaml

    run = tmp_path / "logs" / "ppo" / "PandaLead-v0_1"
    path = save_ppo(run / "PandaLead-v0.zip")
    params = run / "PandaLead-v0"
    params.mkdir()
    (params / "args.yml").write_text(zoo_yaml(env_kwargs="null"))
    levels = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for k in range(1, 7):
        levels.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]")
    (params / "config.yml").write_text("\n".join(levels) + "\nnormalize: *a6\n")
    message = refused(path, "uses a YAML alias")
    assert len(message) < 600


# --- a run folder: progress.csv, best.json, train.py's values (#5, #6, #24, #25, #34) --------

def _crash_on_fsync(monkeypatch):
    """Make the next atomic write of progress.csv die after writing, before its rename."""
    from panda_lead.training import callbacks

    def killed(fd):
        raise RuntimeError("killed before the rename")

    monkeypatch.setattr(callbacks.os, "fsync", killed)


def test_progress_csv_survives_a_crash_while_it_is_continued(tmp_path, monkeypatch):
    """#5: on --resume, SB3's "w+" open truncated progress.csv before its rows were written
    back: a crash in between emptied the run's log (3,527 -> 0 bytes)."""
    from panda_lead.training.callbacks import _AppendingCSV

    path = tmp_path / "progress.csv"
    rows = "eval/mean_error_cm,time/total_timesteps\n5.1,512\n4.2,1024\n"
    path.write_text(rows)
    with monkeypatch.context() as m:
        _crash_on_fsync(m)
        with pytest.raises(RuntimeError, match="killed"):
            _AppendingCSV(path)
    assert path.read_text() == rows
    assert [f.name for f in tmp_path.iterdir()] == ["progress.csv"]  # no temporary left
    out = _AppendingCSV(path)
    out.write({"eval/mean_error_cm": 3.3, "time/total_timesteps": 1536}, {"eval/mean_error_cm":
              None, "time/total_timesteps": None})
    out.close()
    assert path.read_text() == rows + "3.3,1536\n"


def test_a_new_column_is_added_in_a_new_copy_of_progress_csv(tmp_path, monkeypatch):
    """SB3 adds a column (the first evaluation's keys, after training rows) by rewriting the
    file in place from its start: a crash or a reader in the middle saw old and new rows mixed.
    Here the old file stays whole until the new copy replaces it; the old rows are padded."""
    from panda_lead.training.callbacks import _AppendingCSV

    path = tmp_path / "progress.csv"
    out = _AppendingCSV(path)
    out.write({"time/total_timesteps": 512}, {"time/total_timesteps": None})
    out.write({"time/total_timesteps": 1024}, {"time/total_timesteps": None})
    before = path.read_text()
    assert before == "time/total_timesteps\n512\n1024\n"
    row = {"time/total_timesteps": 1536, "eval/mean_error_cm": 4.2, "eval/note": "a,b"}
    excluded = dict.fromkeys(row)
    with monkeypatch.context() as m:
        _crash_on_fsync(m)
        with pytest.raises(RuntimeError, match="killed"):
            out.write(row, excluded)
    assert path.read_text() == before
    out.write(row, excluded)
    out.write({"time/total_timesteps": 2048}, {"time/total_timesteps": None})
    out.close()
    assert path.read_text() == ("time/total_timesteps,eval/mean_error_cm,eval/note\n"
                                "512,,\n1024,,\n1536,4.2,\"a,b\"\n2048,,\n")


@pytest.mark.parametrize("damage", ["folder", "latin1"])
def test_a_progress_csv_that_cannot_be_continued_is_one_line(tmp_path, damage):
    """#24: progress.csv as a folder, or not UTF-8: tracebacks on --resume."""
    from panda_lead.training.callbacks import _AppendingCSV

    path = tmp_path / "progress.csv"
    if damage == "folder":
        path.mkdir()
    else:
        path.write_bytes(b"eval/mean_error_cm\n\xe9\xff\n")
    with pytest.raises(UserError, match="progress.csv.*move it away to resume"):
        _AppendingCSV(path)


@pytest.fixture
def run_with_best(tmp_path):
    """A run folder whose best_model.zip (an untrained policy) records a 12.68 cm evaluation
    in its sidecar, saved as train.py saves it."""
    from stable_baselines3 import PPO
    from test_adopt import Spaces

    from panda_lead import models
    from panda_lead.config import EnvConfig

    obs_space, _ = models.spaces_for(EnvConfig())
    ppo = PPO("MlpPolicy", Spaces(obs_space.shape[0]), n_steps=64, batch_size=64, device="cpu")
    models.save_model(ppo, tmp_path / "best_model.zip",
                      {"env_config": EnvConfig().to_dict(), "timesteps": 2048,
                       "eval_metrics": {"mean_error_cm": 12.68, "in_band_pct": 31.0}})
    return tmp_path


@pytest.mark.parametrize("best_json", [None, "{", '{"timesteps": 512, "mean_error_cm": -1.0}',
                                       '{"timesteps": 512, "mean_error_cm": 0.5}'])
def test_best_json_is_rebuilt_from_the_best_models_sidecar(run_with_best, best_json):
    """#6: best.json was bound to nothing. Missing, the resumed run's first evaluation replaced
    best_model.zip, better or not; edited to -1, no best was saved again; 0.5 was summarised
    as 0.5 while the bound sidecar says 12.68 cm. #24: '{' was a traceback."""
    from panda_lead.models import file_sha256
    from panda_lead.training.callbacks import resume_best

    best_file = run_with_best / "best.json"
    if best_json is not None:
        best_file.write_text(best_json)
    assert resume_best(run_with_best) == (12.68, 2048)
    written = json.loads(best_file.read_text())
    assert written["mean_error_cm"] == 12.68 and written["timesteps"] == 2048
    assert written["model_sha256"] == file_sha256(run_with_best / "best_model.zip")


def test_a_best_model_that_cannot_be_checked_stops_the_resume(run_with_best):
    from panda_lead.training.callbacks import resume_best

    side = run_with_best / "best_model.json"
    side.write_text(side.read_text().replace("12.68", "0.5"))
    with pytest.raises(UserError, match="its best model cannot be checked"):
        resume_best(run_with_best)


def test_without_a_best_model_every_evaluation_may_be_the_best(tmp_path):
    from panda_lead.training.callbacks import resume_best

    (tmp_path / "best.json").write_text('{"mean_error_cm": 0.5}')
    assert resume_best(tmp_path) == (math.inf, None)


@pytest.mark.parametrize("field,value", [
    ("seed", -1), ("seed", 2**64), ("torch_threads", 1_000_000), ("n_workers", 10**6),
    ("eval_steps", 10**9), ("timesteps", 10**24),
])
def test_train_values_beyond_their_bounds_are_refused_before_any_folder(tmp_path, field, value):
    """#25, #34: --seed -1 / 2^64 and --torch-threads 10^6 were tracebacks that left a run
    folder; --eval-steps 10^9 was refused only after training started; --timesteps 10^24 ran
    (and its note named a float-rounded step count)."""
    from panda_lead.cli.train import parse_args

    with pytest.raises(UserError, match=f"--{field.replace('_', '-')} must be an integer in"):
        parse_args([f"--{field.replace('_', '-')}", str(value), "--runs-dir", str(tmp_path)])
    assert not list(tmp_path.iterdir())


def test_memory_estimate_counts_stacked_observations():
    """Issue 38: memory_estimate ignored obs_stack (a stack of 16 needs 16x the buffer)."""
    from panda_lead.config import OBS_FEATURES, EnvConfig
    from panda_lead.training.config import TrainConfig, memory_estimate

    one = TrainConfig(n_envs=1024, n_steps=1024)
    stacked = TrainConfig(env=EnvConfig(obs_stack=16), n_envs=1024, n_steps=1024)
    extra = memory_estimate(stacked) - memory_estimate(one)
    obs = sum(OBS_FEATURES[f] for f in EnvConfig().obs_features)
    # the rollout buffer's observations (float32) grow by 15 frames; the first layer too
    assert extra >= 1024 * 1024 * 15 * obs * 4


def test_the_vec_env_is_closed_when_training_fails_after_it_is_made(tmp_path, monkeypatch):
    """Issue 38: vec.close() was outside any finally: an error between making the envs and
    the end of learning left them (and a subproc env's workers) open."""
    from panda_lead.cli.train import parse_args
    from panda_lead.training import loop

    closed = []

    class Envs:
        def close(self):
            closed.append(True)

    monkeypatch.setattr(loop, "make_vec_env", lambda *a, **k: Envs())
    args = parse_args(["--timesteps", "512", "--n-envs", "2", "--n-steps", "64", "--batch-size",
                       "64", "--eval-freq", "0", "--curriculum-steps", "0", "--no-progress",
                       "--runs-dir", str(tmp_path)])
    with pytest.raises(Exception):  # noqa: B017 (SB3 refuses the stand-in: any error will do)
        loop.train(args)
    assert closed == [True]


# --- eval.py's random seed, and seeds stated once (issue 38) ---------------------------------

def test_a_random_episode_seed_is_a_test_seed(monkeypatch):
    """Issue 38: a random --seed was drawn from 0..2^31-1: a training trajectory 99.5% of the
    time. It is drawn from the test set, and --help says so."""
    from panda_lead.cli import run
    from panda_lead.seeds import TEST_SEEDS, TRAIN_SEED_LOW

    rng = np.random.default_rng(0)
    drawn = {run.random_test_seed(rng) for _ in range(2000)}
    assert drawn <= set(TEST_SEEDS) and len(drawn) > 800
    assert max(drawn) < TRAIN_SEED_LOW
    assert "(default: a random test seed, 0-999," in Path(run.__file__).read_text()  # --help
    with pytest.raises(UserError, match="--seed must be an integer in 0..9223372036854775807"):
        run._validate(run.Args(seed=-1))


# --- the ILC oracle: streamed, and a replay that ends early is charged (#19; issue 38) --------

def _oracle_with(monkeypatch, played, edit=lambda r: r, check=lambda: None):
    """learn_leads on seeds 0-3 with iter_record replaced by the played episodes (copied,
    ``edit``-ed), ``check()`` run before each episode is handed over."""
    from panda_lead import ilc
    from panda_lead.config import EnvConfig

    def fake_iter_record(config, act, seeds, shapes, **kw):
        for r in played:
            check()
            yield edit(copy(r))

    monkeypatch.setattr(ilc, "iter_record", fake_iter_record)
    config = EnvConfig().replace(episode_steps=STEPS)
    return ilc.learn_leads(config, [0, 1, 2, 3], None, ilc.ILCConfig(iterations=2), None)


def test_an_ilc_replay_that_ends_early_is_charged_not_a_crash(monkeypatch, played):
    """Issue 38: a replay that ended early (shorter rollout) crashed np.stack."""
    def fail_seed_1(r):
        if r.seed == 1:
            for k in keys(r):
                setattr(r, k, getattr(r, k)[:20])
            r.meta["failure"] = "unstable"
        return r

    leads, history = _oracle_with(monkeypatch, played, fail_seed_1)
    assert leads.shape == (4, STEPS, 3) and all(math.isfinite(h) for h in history)
    clean, _ = _oracle_with(monkeypatch, played)
    # seed 1 is charged (frozen tip after 0.2 s): a higher first-replay error than played whole
    assert history[0] > _oracle_with(monkeypatch, played)[1][0]
    assert np.array_equal(leads[0], clean[0])


def test_the_ilc_oracle_keeps_no_list_of_rollouts(monkeypatch, played):
    """#19: learn_leads listed every rollout of the set at once (10-15 GB at the 100,000-seed
    cap); it now holds at most the one it is reading."""
    import gc
    import weakref

    handed: list = []
    alive_at_handover: list[int] = []

    def check():
        gc.collect()
        alive_at_handover.append(sum(ref() is not None for ref in handed))

    def track(r):
        handed.append(weakref.ref(r))
        return r

    _oracle_with(monkeypatch, played, track, check)
    assert max(alive_at_handover) <= 1


# --- one findings rule, in code (issue 38) -----------------------------------------------------

def test_a_finding_needs_the_ci_the_pairs_and_the_holm_p():
    """Issue 38: README called a difference a finding when its CI excludes 0 AND its Holm p
    is below 0.05, while the code's "shown" was the CI and >= 10 pairs, and the study
    comparisons computed no p at all. One rule: metrics.finding_verdict."""
    from panda_lead.metrics import Row, claim, finding_verdict

    assert finding_verdict((-2.0, -1.0), 1000, 0.001) == "shown"
    assert finding_verdict((-2.0, 0.1), 1000, 0.001) == "not shown"
    assert finding_verdict((-2.0, -1.0), 9, 0.001).startswith("not shown (only 9 pairs")
    assert finding_verdict((-2.0, -1.0), 1000, 0.2).startswith("not shown (CI excludes 0 but")
    row = Row("mean_err", "mean error (cm)", "lower", 5.0, 1.0, 5.0, 4.0, 1.0, 4.0, 30, 30, 30,
              -1.0, (-1.5, -0.5), -1.0, (-1.5, -0.5), 25, 0.01, p_holm=0.2)
    assert "mean diff -1.00 [-1.50, -0.50] not shown" in claim(row)
    row.p_holm = 0.001
    assert "mean diff -1.00 [-1.50, -0.50] shown" in claim(row)


def test_a_study_comparison_gets_a_holm_adjusted_bootstrap_p():
    from panda_lead.metrics import bootstrap_p, bootstrap_verdicts

    boots = np.concatenate([np.full(20, -0.1), np.linspace(0.1, 1.0, 980)])  # 2% at or below 0
    ci = tuple(np.percentile(boots, [2.5, 97.5]))
    assert ci[0] > 0 and bootstrap_p(boots) == pytest.approx(0.04)
    assert bootstrap_verdicts([ci], [boots], 1000) == ["shown"]
    # three such metrics in one table: Holm makes 0.04 x 3 = 0.12, no finding
    assert all(v.startswith("not shown (CI excludes 0")
               for v in bootstrap_verdicts([ci] * 3, [boots] * 3, 1000))
