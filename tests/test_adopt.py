"""eval.py --adopt: a foreign SB3 PPO zip becomes a bound, carded archive entry, or is refused
in one line with nothing written; nothing in it is ever unpickled.

The foreign zips are real SB3 saves of untrained models on a stand-in env with the right
spaces (no MuJoCo, no training), edited where a case needs a zip SB3 would not write."""

import json
import os
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from panda_lead.adopt import inspect
from panda_lead.cli import models as model_commands
from panda_lead.config import OBS_29, EnvConfig
from panda_lead.models import ModelError, load_policy, verify


class Spaces(gym.Env):
    def __init__(self, obs_dim=15, act_dim=3, bound=1.0):
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-bound, bound, (act_dim,), np.float32)


def save_ppo(path: Path, algo="PPO", obs_dim=15, act_dim=3, bound=1.0, **kwargs) -> Path:
    import stable_baselines3

    cls = getattr(stable_baselines3, algo)
    extra = {"n_steps": 64, "batch_size": 64} if algo == "PPO" else {}
    if algo == "SAC":
        extra = {"buffer_size": 100}
    model = cls("MlpPolicy", Spaces(obs_dim, act_dim, bound), device="cpu", seed=0,
                **extra, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    return path


def edit_member(path: Path, member: str, edit) -> None:
    """Rewrite one member of a zip: edit(bytes) -> bytes."""
    with zipfile.ZipFile(path) as z:
        members = {i.filename: z.read(i) for i in z.infolist()}
    members[member] = edit(members[member])
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)


def edit_data(path: Path, edit) -> None:
    def change(raw: bytes) -> bytes:
        data = json.loads(raw)
        edit(data)
        return json.dumps(data).encode()

    edit_member(path, "data", change)


def cli(argv, cwd: Path, capsys):
    """eval.py's model-file command in this process: -> (exit status, stdout, stderr)."""
    old = os.getcwd()
    os.chdir(cwd)
    try:
        model_commands.main([str(a) for a in argv], "eval.py")
        code = 0
    except SystemExit as exc:
        code = exc.code
    finally:
        os.chdir(old)
    out = capsys.readouterr()
    return code, out.out, out.err


def refused(path: Path, match: str, config: EnvConfig | None = None) -> str:
    with pytest.raises(ModelError, match=match) as exc:
        inspect(path, config or EnvConfig())
    message = str(exc.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    return message


# --- what is inferred ------------------------------------------------------------------------
def test_inspect_infers_the_policy_from_weights_and_data(tmp_path):
    plain = inspect(save_ppo(tmp_path / "a.zip"), EnvConfig())
    assert plain.spec == {"net_arch": [64, 64], "activation_fn": "tanh", "log_std_init": 0.0}
    assert plain.timesteps == 0 and plain.hyperparams["n_steps"] == 64

    split = inspect(save_ppo(tmp_path / "b.zip", policy_kwargs=dict(
        net_arch=dict(pi=[32], vf=[16, 16]), activation_fn=torch.nn.ReLU, log_std_init=-0.5)),
        EnvConfig())
    assert split.spec == {"net_arch": {"pi": [32], "vf": [16, 16]}, "activation_fn": "relu",
                          "log_std_init": -0.5}


def test_log_std_init_comes_from_the_tensor_when_not_stated(tmp_path):
    path = save_ppo(tmp_path / "m.zip")

    def shift(raw: bytes) -> bytes:
        import io

        state = torch.load(io.BytesIO(raw), weights_only=True)
        state["log_std"] = torch.full_like(state["log_std"], -1.25)
        out = io.BytesIO()
        torch.save(state, out)
        return out.getvalue()

    edit_member(path, "policy.pth", shift)
    assert inspect(path, EnvConfig()).spec["log_std_init"] == -1.25


def test_a_29_d_model_is_adopted_with_the_features_the_refusal_names(tmp_path):
    path = save_ppo(tmp_path / "m.zip", obs_dim=29)
    message = refused(path, "29-D observation")
    assert "--env.obs-features ee_pos ee_vel target_pos target_vel target_acc joint_pos " \
           "joint_vel" in message
    assert inspect(path, EnvConfig(obs_features=OBS_29)).spec["net_arch"] == [64, 64]
    stacked = save_ppo(tmp_path / "s.zip", obs_dim=45)
    assert "--env.obs-stack 3" in refused(stacked, "45-D observation")


# --- what is refused, each in one line ---------------------------------------------------------
def test_files_that_are_not_sb3_ppo_zips_are_refused(tmp_path):
    bad = tmp_path / "notzip.zip"
    bad.write_bytes(b"not a zip")
    refused(bad, "not a model zip")
    nodata = tmp_path / "nodata.zip"
    with zipfile.ZipFile(nodata, "w") as z:
        z.writestr("policy.pth", b"")
    refused(nodata, "no data in the zip")
    garbage = save_ppo(tmp_path / "garbage.zip")
    edit_member(garbage, "data", lambda raw: b"\x80\x04not json")
    refused(garbage, "not JSON")
    refused(save_ppo(tmp_path / "a2c.zip", algo="A2C"), "not a PPO model")
    refused(save_ppo(tmp_path / "sac.zip", algo="SAC"), "only MlpPolicy")


def test_policies_this_repo_cannot_rebuild_are_refused(tmp_path):
    refused(save_ppo(tmp_path / "sde.zip", use_sde=True), "gSDE")
    refused(save_ppo(tmp_path / "elu.zip", policy_kwargs=dict(activation_fn=torch.nn.ELU)),
            "activation is <class 'torch.nn.modules.activation.ELU'>; only tanh and relu")

    cnn = save_ppo(tmp_path / "cnn.zip")
    edit_data(cnn, lambda d: d["policy_class"].update(
        __init__="<function ActorCriticCnnPolicy.__init__ at 0x7f>"))
    refused(cnn, "its policy is ActorCriticCnnPolicy")

    squash = save_ppo(tmp_path / "squash.zip", policy_kwargs=dict(net_arch=[64, 64]))
    edit_data(squash, lambda d: d["policy_kwargs"].update(squash_output=True))
    refused(squash, "squash_output")

    extractor = save_ppo(tmp_path / "ext.zip", policy_kwargs=dict(net_arch=[64, 64]))
    edit_data(extractor, lambda d: d["policy_kwargs"].update(
        features_extractor_class="<class 'mine.Encoder'>"))
    refused(extractor, "features extractor is <class 'mine.Encoder'>")

    unknown = save_ppo(tmp_path / "unknown.zip", policy_kwargs=dict(net_arch=[64, 64]))
    edit_data(unknown, lambda d: d["policy_kwargs"].update(dropout=0.1))
    refused(unknown, "policy_kwargs set dropout")

    lying = save_ppo(tmp_path / "lying.zip", policy_kwargs=dict(net_arch=[64, 64]))
    edit_data(lying, lambda d: d["policy_kwargs"].update(net_arch=[128, 128]))
    refused(lying, r"say net_arch \[128, 128\] but its weights have pi \[64, 64\]")

    wide = save_ppo(tmp_path / "wide.zip", policy_kwargs=dict(net_arch=[8, 8, 8, 8, 8, 8, 8, 8, 8]))
    refused(wide, "1-8 layer widths")


def test_spaces_must_be_the_envs(tmp_path):
    seven = save_ppo(tmp_path / "joint.zip", act_dim=7)
    assert "--env.action joint or joint_target has 7" in refused(seven, "action is 7-D")
    assert inspect(seven, EnvConfig(action="joint")).spec["net_arch"] == [64, 64]
    refused(save_ppo(tmp_path / "wide.zip", bound=2.0), r"action bounds .* not the env's \[-1, 1\]")
    flat = save_ppo(tmp_path / "img.zip")
    edit_data(flat, lambda d: d["observation_space"].update(_shape=[3, 5]))
    refused(flat, "one flat vector")
    discrete = save_ppo(tmp_path / "disc.zip")
    edit_data(discrete, lambda d: d["action_space"].update({
        ":type:": "<class 'gymnasium.spaces.discrete.Discrete'>"}))
    refused(discrete, "action_space is <class 'gymnasium.spaces.discrete.Discrete'>")


def test_weights_are_read_as_tensors_only(tmp_path):
    """A policy.pth whose pickle would run code is refused by torch, and the code never runs."""
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path = save_ppo(tmp_path / "evil.zip")

    def evil(raw: bytes) -> bytes:
        import io

        out = io.BytesIO()
        torch.save({"log_std": Payload()}, out)
        return out.getvalue()

    edit_member(path, "policy.pth", evil)
    refused(path, "policy.pth: UnpicklingError")
    assert not marker.exists()

    nan = save_ppo(tmp_path / "nan.zip")

    def poison(raw: bytes) -> bytes:
        import io

        state = torch.load(io.BytesIO(raw), weights_only=True)
        state["action_net.bias"][0] = float("nan")
        out = io.BytesIO()
        torch.save(state, out)
        return out.getvalue()

    edit_member(nan, "policy.pth", poison)
    refused(nan, "NaN or infinite")


def test_a_zip_bomb_costs_one_line(tmp_path):
    path = tmp_path / "bomb.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("data", b"{" + b" " * (65 * 2**20) + b"}")
    assert path.stat().st_size < 2**20
    refused(path, "would expand")


def zoo_yaml(**settings) -> str:
    """A config.yml / args.yml as RL Zoo writes it (yaml.dump of an OrderedDict)."""
    pairs = "".join(f"  - - {k}\n    - {v}\n" for k, v in settings.items())
    return "!!python/object/apply:collections.OrderedDict\n- " + pairs[2:]


def test_vecnormalize_and_rl_zoo_env_kwargs_are_checked(tmp_path):
    run = tmp_path / "logs" / "ppo" / "PandaLead-v0_1"
    path = save_ppo(run / "PandaLead-v0.zip")
    params = run / "PandaLead-v0"
    params.mkdir()
    (params / "args.yml").write_text(zoo_yaml(env_kwargs="null"))
    (params / "config.yml").write_text(zoo_yaml(env_kwargs="{max_lead: 0.1}", normalize="false"))
    message = refused(path, "RL Zoo trained it with max_lead = 0.1")
    assert "--env.max-lead" in message
    assert inspect(path, EnvConfig(max_lead=0.1)).zoo_run == str(params)

    (params / "config.yml").write_text(zoo_yaml(normalize="true"))
    refused(path, "trained with VecNormalize .*normalize: True")
    (params / "config.yml").write_text(zoo_yaml(normalize="false"))
    (params / "vecnormalize.pkl").write_bytes(b"never read")
    message = refused(path, "trained with VecNormalize .*vecnormalize.pkl")
    assert "never unpickles" in message and "normalize: False" in message

    (params / "vecnormalize.pkl").unlink()
    (params / "config.yml").write_text("!!python/object/apply:os.system [echo hi]\n")
    refused(path, "cannot read RL Zoo.s settings in .*config.yml safely")


# --- through eval.py's command line ------------------------------------------------------------
def test_bad_input_is_one_error_line_and_nothing_is_written(tmp_path, capsys):
    path = save_ppo(tmp_path / "m.zip", obs_dim=12)
    for argv, words in (
            (["--adopt", path, "--name", "m"], "12-D observation"),
            (["--adopt", path, "--name", "../m", "--env.obs-features", "ee_pos", "ee_vel",
              "target_pos", "target_vel"], "--name must be a plain name"),
            (["--adopt", tmp_path / "absent.zip", "--name", "m"], "model not found"),
            (["--adopt", path, "--name", "m", "--env.max-lead", "-1"], "max_lead"),
            (["--adopt", path, "--name", "m", "--model", path, "--restore-sidecar"],
             "separate commands")):
        code, out, err = cli(argv, tmp_path, capsys)
        assert code == 2, (argv, out, err)
        assert err.startswith("error: ") and err.count("\n") == 1 and words in err, err
    assert not (tmp_path / "archive").exists()


def test_adopted_model_is_a_bound_carded_archive_entry(tmp_path, capsys):
    """One full adoption: the archived pair loads weights only, acts exactly as the foreign
    policy did, carries provenance, and its name is then taken until --force."""
    from stable_baselines3 import PPO

    src = save_ppo(tmp_path / "mine.zip", policy_kwargs=dict(
        net_arch=dict(pi=[32, 32], vf=[64]), activation_fn=torch.nn.ReLU, log_std_init=-1.0))
    code, out, err = cli(["--adopt", src, "--name", "mine"], tmp_path, capsys)
    assert code == 0, err
    assert "adopted" in out and "archive/mine.zip" in out
    archive = tmp_path / "archive"
    assert sorted(p.name for p in archive.iterdir() if not p.name.startswith(".")) == [
        "mine.json", "mine.md", "mine.zip"]
    side = verify(archive / "mine.zip")
    assert side["policy"] == {"net_arch": {"pi": [32, 32], "vf": [64]}, "activation_fn": "relu",
                              "log_std_init": -1.0}
    assert side["env_config"] == EnvConfig().to_dict() and "train_config" not in side
    assert side["source"] == str(src) and side["adopted"]["algo"] == "PPO"
    assert len(side["adopted"]["sha256"]) == 64 and side["test_metrics"]["mean_error_cm"] > 0
    card = (archive / "mine.md").read_text()
    assert f"Adopted from `{src}`" in card and f"{side['test_seed0_mean_error_cm']:.6f}" in card

    policy, _, _ = load_policy(archive / "mine.zip")
    foreign = PPO.load(src, device="cpu")  # our own file, written above by this test
    obs = np.random.default_rng(0).normal(size=(16, 15)).astype(np.float32)
    with torch.no_grad():
        mine = policy.get_distribution(torch.as_tensor(obs)).distribution.mean
        theirs = foreign.policy.get_distribution(torch.as_tensor(obs)).distribution.mean
    assert torch.equal(mine, theirs)
    with zipfile.ZipFile(archive / "mine.zip") as z:  # a fresh SB3 zip made here
        data = json.loads(z.read("data"))
    assert data["policy_kwargs"]["log_std_init"] == -1.0

    code, _, err = cli(["--adopt", src, "--name", "mine"], tmp_path, capsys)
    assert code == 2 and "exists" in err and "--force" in err
    before = (archive / "mine.json").read_text()
    code, _, err = cli(["--adopt", src, "--name", "mine", "--force"], tmp_path, capsys)
    assert code == 0, err
    after = json.loads((archive / "mine.json").read_text())
    assert after["test_metrics"] == json.loads(before)["test_metrics"]
    verify(archive / "mine.zip")


def test_a_model_of_this_repo_is_adopted_with_its_own_env_and_the_flags_given(tiny_run, tmp_path,
                                                                             capsys):
    """Adopting one of this repo's models starts from its sidecar's env, not the defaults: a
    deployment setting (the lead's low-pass under noise) becomes an archive entry of its own,
    the weights unchanged."""
    from panda_lead.models import copy_with_sidecar

    tmp, _, _, _ = tiny_run
    tiny = tmp / "archive" / "tiny.zip"
    env = {**verify(tiny)["env_config"], "max_lead": 0.1}  # not the default
    src = tmp_path / "src.zip"
    copy_with_sidecar(tiny, src, {"env_config": env})
    code, out, err = cli(["--adopt", src, "--name", "smoothed", "--env.noisy-lead-filter-hz",
                          "10"], tmp_path, capsys)
    assert code == 0, err
    side = verify(tmp_path / "archive" / "smoothed.zip")
    assert side["env_config"] == {**env, "noisy_lead_filter_hz": 10.0}
    assert side["adopted"]["env_changed"] == {"noisy_lead_filter_hz": 10.0}
    card = (tmp_path / "archive" / "smoothed.md").read_text()
    assert "its weights unchanged; run with noisy_lead_filter_hz = 10.0" in card
    mine, _, _ = load_policy(tmp_path / "archive" / "smoothed.zip")
    theirs, _, _ = load_policy(src)
    assert all(torch.equal(a, b) for a, b in zip(mine.state_dict().values(),
                                                 theirs.state_dict().values(), strict=True))
