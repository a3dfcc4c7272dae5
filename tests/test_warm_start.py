"""--init-from: a run that starts from a trained model's weights (training/warm_start.py). Its
first policy's mean and its value are the model's exactly, also when it observes more (the new inputs at
zero weight, each old input found by name in the canonical order); what does not fit is one
line before a run folder is made; the sidecars name the model it started from."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from panda_lead.cli.train import parse_args
from panda_lead.config import OBS_15, EnvConfig, obs_layout
from panda_lead.errors import UserError
from panda_lead.models import file_sha256, load_policy
from panda_lead.training import TrainConfig
from panda_lead.training.archive import write_card
from panda_lead.training.envs import make_vec_env
from panda_lead.training.fast_ppo import build_ppo
from panda_lead.training.warm_start import check_init_from, warm_start

ROOT = Path(__file__).resolve().parents[1]
START = ROOT / "archive" / "seeds" / "v5_err_decay_kept_s1.zip"  # 18-D: OBS_15 + tip_error
TEMPLATE = str(START).replace("_s1.zip", "_s{seed}.zip")
TINY = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
        "--n-workers", "1", "--no-progress"]


def _built(features, **kw):
    config = TrainConfig(env=EnvConfig(obs_features=features), n_envs=2, n_steps=64,
                         batch_size=64, seed=1, init_from=TEMPLATE, **kw)
    vec = make_vec_env(config.env, config.n_envs, config.seed, config.vec_env, 1)
    return config, vec, build_ppo(config, vec)


def test_a_warm_started_policy_acts_and_values_as_its_model_on_the_inputs_they_share():
    # prev_action sorts before tip_error and installation after it (config.OBS_FEATURES): a
    # prefix copy of the first layer would put tip_error's weights on prev_action's columns.
    features = OBS_15 + ("tip_error", "prev_action", "installation", "target_preview")
    config, vec, model = _built(features)
    try:
        record = warm_start(model, config.init_from, config)
        old, old_env, _ = load_policy(START)
        rng = np.random.default_rng(0)
        new_obs = rng.normal(size=(64, model.observation_space.shape[0])).astype(np.float32)
        old_cols = {f: (a, b) for f, a, b in obs_layout(features)}
        old_obs = np.concatenate([new_obs[:, slice(*old_cols[f])]
                                  for f in old_env["obs_features"]], axis=1)
        with torch.no_grad():
            for policy in (model.policy, old):
                policy.set_training_mode(False)
            new_mean = model.policy.get_distribution(torch.as_tensor(new_obs)).distribution.mean
            old_mean = old.get_distribution(torch.as_tensor(old_obs)).distribution.mean
            np.testing.assert_allclose(new_mean.numpy(), old_mean.numpy(), atol=1e-6)
            np.testing.assert_allclose(model.policy.predict_values(torch.as_tensor(new_obs)),
                                       old.predict_values(torch.as_tensor(old_obs)), atol=1e-6)
            # exploration restarts at the run's own std (a trained lead's is too narrow to move)
            np.testing.assert_array_equal(model.policy.log_std.numpy(), config.log_std_init)
        assert record == {"path": str(START), "sha256": file_sha256(START)}
        # and the new inputs matter to nothing yet: changing them leaves the action alone
        moved = new_obs.copy()
        a, b = old_cols["target_preview"]
        moved[:, a:b] += 3.0
        with torch.no_grad():
            again = model.policy.get_distribution(torch.as_tensor(moved)).distribution.mean
        np.testing.assert_allclose(again.numpy(), new_mean.numpy(), atol=1e-6)
    finally:
        vec.close()


def test_init_keep_std_continues_at_the_models_trained_exploration():
    config, vec, model = _built(OBS_15 + ("tip_error",), init_keep_std=True)
    try:
        warm_start(model, config.init_from, config)
        old = load_policy(START)[0]
        trained = old.log_std.detach().numpy()
        assert np.all(trained < config.log_std_init - 1.0)  # a trained lead explores narrowly
        np.testing.assert_array_equal(model.policy.log_std.detach().numpy(), trained)
    finally:
        vec.close()
    with pytest.raises(UserError, match="needs --init-from"):
        TrainConfig(init_keep_std=True)



    """obs_stack 3 from a model that saw one observation: the newest block (recent_actions
    added) holds the model's weights, the two older blocks are new inputs at zero weight."""
    features = OBS_15 + ("tip_error", "recent_actions")
    config = TrainConfig(env=EnvConfig(obs_features=features, obs_stack=3), n_envs=2,
                         n_steps=64, batch_size=64, seed=1, init_from=TEMPLATE)
    vec = make_vec_env(config.env, config.n_envs, config.seed, config.vec_env, 1)
    try:
        model = build_ppo(config, vec)
        warm_start(model, config.init_from, config)
        old, old_env, _ = load_policy(START)
        base = obs_layout(features)[-1][2]
        assert model.observation_space.shape[0] == 3 * base
        cols = {f: (a, b) for f, a, b in obs_layout(features)}
        rng = np.random.default_rng(1)
        new_obs = rng.normal(size=(32, 3 * base)).astype(np.float32)
        old_obs = np.concatenate([new_obs[:, slice(*cols[f])] for f in old_env["obs_features"]],
                                 axis=1)
        moved = new_obs.copy()
        moved[:, base:] += 5.0  # the older observations, and the newest's recent actions
        moved[:, slice(*cols["recent_actions"])] -= 2.0
        with torch.no_grad():
            for policy in (model.policy, old):
                policy.set_training_mode(False)
            means = [policy.get_distribution(torch.as_tensor(o)).distribution.mean.numpy()
                     for policy, o in ((model.policy, new_obs), (old, old_obs),
                                       (model.policy, moved))]
        np.testing.assert_allclose(means[0], means[1], atol=1e-6)
        np.testing.assert_allclose(means[2], means[0], atol=1e-6)
    finally:
        vec.close()


def test_a_model_that_stacks_more_than_the_run_is_one_line():
    stacked = str(ROOT / "archive" / "seeds" /
                  "deploy_large_batch_curv10_actions_stack4_continued_5m_s{seed}.zip")
    features = tuple(load_policy(stacked.format(seed=1))[1]["obs_features"])
    config = TrainConfig(env=EnvConfig(obs_features=features, obs_stack=2), init_from=stacked,
                         seed=1)
    with pytest.raises(UserError, match="it stacks 4 observations, this run 2"):
        check_init_from(config.init_from, config.seed, config)


@pytest.mark.parametrize("features, kw, words", [
    (OBS_15 + ("tip_error",), dict(net_arch=(256, 256)), "net_arch is [64, 64]"),
    (OBS_15, {}, "it observes tip_error, which this run does not"),
    (OBS_15 + ("tip_error",), dict(env=dict(action="joint")), "its action is 'lead'"),
])
def test_a_model_that_does_not_fit_the_run_is_one_line(features, kw, words):
    env = dict(obs_features=features, **kw.pop("env", {}))
    config = TrainConfig(env=EnvConfig(**env), init_from=TEMPLATE, seed=1, **kw)
    with pytest.raises(UserError, match=words.replace("[", r"\[").replace("]", r"\]")):
        check_init_from(config.init_from, config.seed, config)


@pytest.mark.parametrize("value, words", [("archive/x_{seeds}.zip", "{seed} the only"),
                                          ("  ", "a model's path")])
def test_an_init_from_that_is_no_path_template_is_refused(value, words):
    with pytest.raises(UserError, match=words.replace("{", r"\{").replace("}", r"\}")):
        TrainConfig(init_from=value)


def test_a_missing_starting_model_is_refused_before_a_run_folder_exists(tmp_path):
    from panda_lead.training import train

    args = parse_args(["--init-from", str(tmp_path / "none_s{seed}.zip"), "--seed", "3",
                       "--runs-dir", str(tmp_path / "runs"), *TINY])
    with pytest.raises(UserError, match="none_s3.zip: no such model"):
        train(args)
    assert not (tmp_path / "runs").exists()


def test_a_warm_started_runs_models_name_what_it_started_from_and_resume_keeps_it(tmp_path):
    from panda_lead.training import train

    runs = tmp_path / "runs"
    args = ["--init-from", TEMPLATE, "--seed", "1", "--env.obs-features", *OBS_15,
            "tip_error", "prev_action", "--eval-freq", "0", "--runs-dir", str(runs), *TINY]
    run_dir = train(parse_args([*args, "--timesteps", "128"]))
    expected = {"path": str(START), "sha256": file_sha256(START)}
    assert json.loads((run_dir / "final_model.json").read_text())["init_from"] == expected
    train(parse_args(["--resume", str(run_dir), "--timesteps", "256", "--no-progress"]))
    side = json.loads((run_dir / "final_model.json").read_text())
    assert side["timesteps"] == 256 and side["init_from"] == expected
    # and its card says its steps are on top of another model's
    card = write_card(run_dir / "final_model.zip", side, seed0=1.0).read_text()
    assert f"Started from `{START}` (sha256 `{expected['sha256'][:12]}`)" in card
