"""The env as Gymnasium users and third-party code treat it (issue 40): max_episode_steps on
every path, copies, reset options, render speed settings and RecordVideo, the headless
behaviours, the manual's observation table, and the command lines' help."""

from __future__ import annotations

import copy
import pickle
import re
import subprocess
import sys

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from conftest import ROOT, run_script

from panda_lead import video
from panda_lead.config import OBS_FEATURES, OBS_SCALE
from panda_lead.env import PandaLeadEnv
from panda_lead.errors import UserError

LONG = 203  # longer than the default episode (200 steps): the length a TimeLimit used to cut


def _episode_length(env, n_envs: int | None = None) -> int:
    """Steps until the (first) episode ends, zero actions."""
    env.reset(seed=0)
    a = np.zeros(3, np.float32) if n_envs is None else np.zeros((n_envs, 3), np.float32)
    for k in range(1, 10_000):
        _, _, terminated, truncated, _ = env.step(a)
        if np.any(terminated) or np.any(truncated):
            assert not np.any(terminated)
            return k
    raise AssertionError("no episode end")


# --- max_episode_steps: the same meaning on every path ------------------------------------------

def _single(**kw):
    e = gym.make("PandaLead-v0", **kw)
    return e, e, None


def _time_limit(max_episode_steps, **kw):
    e = gym.wrappers.TimeLimit(PandaLeadEnv(**kw), max_episode_steps)
    return e, e, None


def _sync(**kw):
    v = gym.make_vec("PandaLead-v0", num_envs=2, vectorization_mode="sync", **kw)
    return v, v.envs[0], 2


def _native(**kw):
    v = gym.make_vec("PandaLead-v0", num_envs=2, **kw)
    return v, v, 2


PATHS = {"make": _single, "sync make_vec": _sync, "native make_vec": _native,
         "TimeLimit(env)": _time_limit}


@pytest.mark.parametrize("path", PATHS)
def test_max_episode_steps_sets_the_episode_length_on_every_path(path):
    env, spec_holder, n = PATHS[path](max_episode_steps=LONG)
    assert _episode_length(env, n) == LONG  # was 200 through make, sync and TimeLimit
    # TimeLimit(PandaLeadEnv()) has no spec: nothing registered made it
    assert path == "TimeLimit(env)" or spec_holder.spec.max_episode_steps == LONG
    # ours (a SyncVectorEnv is Gymnasium's: its spec keeps the argument in its kwargs)
    arm = spec_holder.unwrapped
    assert arm.spec is None or arm.spec.max_episode_steps == LONG
    assert arm.cfg.episode_steps == LONG  # what a sidecar would record
    env.close()


@pytest.mark.parametrize("path", PATHS)
def test_max_episode_steps_beside_a_different_episode_steps_is_refused(path):
    with pytest.raises(UserError, match="episode_steps=5 and max_episode_steps=6 .*disagree"):
        env, _, n = PATHS[path](max_episode_steps=6, episode_steps=5)
        env.reset(seed=0)  # the wrapped single envs learn of their TimeLimit at reset


@pytest.mark.parametrize("path", PATHS)
def test_max_episode_steps_agreeing_with_episode_steps_is_fine(path):
    env, _, n = PATHS[path](max_episode_steps=6, episode_steps=6)
    assert _episode_length(env, n) == 6


def test_a_shorter_time_limit_sets_the_length_too():
    e = gym.make("PandaLead-v0", max_episode_steps=9)
    assert _episode_length(e) == 9 and e.unwrapped.cfg.episode_steps == 9
    assert _episode_length(e) == 9  # the second episode too


def test_a_time_limit_keeps_a_speed_cap_set_before_the_first_reset():
    e = gym.make("PandaLead-v0", max_episode_steps=LONG)
    e.unwrapped.set_speed_cap(1.0)  # the curriculum sets it before training's first reset
    e.reset(seed=0)
    assert e.unwrapped.cfg.episode_steps == LONG and e.unwrapped.task.speed_cap == 1.0
    assert e.unwrapped.traj.peak_speed <= 1.0


# --- copies --------------------------------------------------------------------------------------

@pytest.mark.parametrize("make", [
    lambda: PandaLeadEnv(),
    lambda: gym.make("PandaLead-v0"),
    lambda: gym.make_vec("PandaLead-v0", num_envs=2),
], ids=["env", "gym.make", "make_vec"])
@pytest.mark.parametrize("how", [copy.deepcopy, pickle.dumps], ids=["deepcopy", "pickle"])
def test_copies_are_refused_in_one_line(make, how):
    env = make()
    env.reset(seed=0)
    with pytest.raises(TypeError, match=r"cannot be copied or pickled .*replay") as caught:
        how(env)
    assert "\n" not in str(caught.value)


def test_a_shallow_copy_of_the_env_is_refused_too():
    with pytest.raises(TypeError, match="cannot be copied or pickled"):
        copy.copy(PandaLeadEnv())


# --- reset options -------------------------------------------------------------------------------

BAD_OPTIONS = [
    ({"trajseed": 5}, "unknown reset option 'trajseed'; did you mean 'traj_seed'"),
    ({"traj_seed": 2**70}, "integer in 0..2^63-1"),
    ({"traj_seed": -1}, "integer in 0..2^63-1"),
    ({"traj_seed": 1.5}, "integer in 0..2^63-1"),
    ({"traj_seed": True}, "integer in 0..2^63-1"),
    ({"shape": "fig9"}, "unknown shape 'fig9'; did you mean 'fig8'"),
    ([1, 2], "must be a dict"),
    ("traj_seed", "must be a dict"),
]


@pytest.mark.parametrize("options,words", BAD_OPTIONS)
def test_bad_reset_options_are_one_clear_error(options, words):
    e = gym.make("PandaLead-v0")
    with pytest.raises(UserError, match=re.escape(words)) as caught:
        e.reset(seed=0, options=options)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("options,words", BAD_OPTIONS + [
    ({"traj_seeds": [1, 2**70]}, "integer in 0..2^63-1"),
    ({"shapes": ["circle", "fig9"]}, "unknown shape 'fig9'"),
    ({"traj_seeds": 5}, "must be a list"),
    ({"reset_masks": np.ones(2, bool)}, "did you mean 'reset_mask'"),
])
def test_bad_vector_reset_options_are_one_clear_error(options, words):
    v = gym.make_vec("PandaLead-v0", num_envs=2)
    with pytest.raises(UserError, match=re.escape(words)):
        v.reset(seed=0, options=options)


def test_good_reset_options_still_play_what_they_name():
    e = gym.make("PandaLead-v0")
    assert e.reset(seed=0, options={"traj_seed": np.int64(7)})[1]["traj_seed"] == 7
    _, info = e.reset(seed=0, options={"traj_seed": 2**63 - 1, "shape": "fly"})
    assert info == {"traj_seed": 2**63 - 1, "shape": "fly"}
    drawn = e.reset(seed=3, options={"traj_seed": None})[1]["traj_seed"]
    assert drawn == e.reset(seed=3)[1]["traj_seed"] == e.reset(seed=3, options={})[1]["traj_seed"]
    v = gym.make_vec("PandaLead-v0", num_envs=2)
    _, info = v.reset(options={"traj_seeds": [4, 5], "shapes": [None, "circle"]})
    assert info["traj_seed"].tolist() == [4, 5] and info["shape"][1] == "circle"


# --- rendering -----------------------------------------------------------------------------------

def _frame_with(model, data, samples: int, shadows: bool, reflections: bool) -> np.ndarray:
    saved = model.vis.quality.offsamples
    model.vis.quality.offsamples = samples
    r = mujoco.Renderer(model, 48, 64)
    model.vis.quality.offsamples = saved
    r.update_scene(data, camera="workspace")
    r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(shadows)
    r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = int(reflections)
    frame = r.render()
    r.close()
    return frame


def test_render_uses_the_video_settings_no_shadows_reflections_or_multisampling():
    e = PandaLeadEnv(render_mode="rgb_array", width=64, height=48)
    e.reset(seed=0, options={"traj_seed": 3})
    frame = e.render()  # right after reset: no trail drawn yet
    model, data = e.core.model, e.core.get_data(0)
    assert video.VideoConfig().samples == 0 and not video.VideoConfig().shadows
    assert np.array_equal(frame, _frame_with(model, data, 0, False, False))
    # the scene's own settings (4x multisampling, shadows, the floor's reflection) differ
    assert not np.array_equal(frame, _frame_with(model, data, model.vis.quality.offsamples,
                                                 True, True))
    flags = e._frames._renderer.scene.flags
    assert flags[mujoco.mjtRndFlag.mjRND_SHADOW] == 0
    assert flags[mujoco.mjtRndFlag.mjRND_REFLECTION] == 0
    e.close()


def test_record_video_records_an_episode(tmp_path):
    import imageio.v3 as iio

    e = gym.make("PandaLead-v0", render_mode="rgb_array", width=64, height=48, episode_steps=6)
    e = gym.wrappers.RecordVideo(e, str(tmp_path), episode_trigger=lambda k: True,
                                 disable_logger=True)
    assert _episode_length(e) == 6
    e.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1
    frames = iio.imread(videos[0], plugin="pyav") if _has_pyav() else iio.imread(videos[0])
    assert frames.shape[0] >= 7 and frames.shape[1:3] == (48, 64)  # the reset frame + 6 steps
    assert frames.std() > 0


def _has_pyav() -> bool:
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


# --- headless ------------------------------------------------------------------------------------

@pytest.fixture
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def test_human_render_mode_without_a_display_is_refused_not_an_exit(headless):
    with pytest.raises(UserError, match="needs a display.*rgb_array"):
        PandaLeadEnv(render_mode="human")
    with pytest.raises(UserError, match="needs a display"):
        gym.make("PandaLead-v0", render_mode="human")


def test_check_env_headless_with_its_defaults_raises_and_with_skip_render_check_passes(headless):
    from gymnasium.utils.env_checker import check_env

    e = gym.make("PandaLead-v0", episode_steps=20, width=64, height=48)
    with pytest.raises(UserError, match="needs a display"):  # was: the process ended, exit 1
        check_env(e.unwrapped)
    with pytest.warns(UserWarning, match="observation space"):  # unbounded box: MuJoCo envs too
        check_env(e.unwrapped, skip_render_check=True)


# --- the manual ----------------------------------------------------------------------------------

def _table_rows(text: str, header: str) -> dict[str, list[str]]:
    """A markdown table's rows (first cell, backticks dropped -> the other cells) after the line
    starting with ``header``."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.strip().startswith(header))
    rows = {}
    for ln in lines[start + 2:]:
        if not ln.strip().startswith("|"):
            break
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        rows[cells[0].strip("`")] = cells[1:]
    return rows


@pytest.mark.parametrize("where", ["env docstring", "docs/env.md"])
def test_every_observation_feature_is_in_the_manuals_table_with_its_size_and_scale(where):
    text = (PandaLeadEnv.__doc__ if where == "env docstring"
            else (ROOT / "docs" / "env.md").read_text())
    rows = _table_rows(text, "| feature")
    assert list(rows) == list(OBS_FEATURES)
    for f, (size, _, scale) in rows.items():
        assert int(size) == OBS_FEATURES[f] and float(scale) == OBS_SCALE[f], f


def test_the_manual_says_how_to_check_headless_and_about_torch_threads():
    page = (ROOT / "docs" / "env.md").read_text()
    for text in (page, PandaLeadEnv.__doc__):
        assert "skip_render_check=True" in text and 'render_mode="human"' in text
    assert "torch.set_num_threads(1)" in page


# --- command lines -------------------------------------------------------------------------------

def test_the_console_command_lists_and_dispatches_the_six_scripts(capsys):
    from panda_lead.cli import main as cli

    assert cli.main(["--help"]) == 0
    listed = capsys.readouterr().out
    for name in ("train", "eval", "ikpd", "metrics", "env", "trajectory"):
        assert f"  {name} " in listed
    with pytest.raises(SystemExit) as exit_:
        cli.main(["evl"])
    assert exit_.value.code == 2 and "did you mean 'eval'" in capsys.readouterr().err
    for name in ("eval", "ikpd", "metrics", "trajectory", "env"):
        with pytest.raises(SystemExit) as exit_:
            cli.main([name, "--help"])
        assert exit_.value.code == 0
        assert f"usage: panda-lead {name} " in capsys.readouterr().out


def test_eval_help_shows_adopt_and_names_archives_that_exist(capsys):
    from panda_lead.cli import main as cli

    with pytest.raises(SystemExit):
        cli.main(["eval", "--help"])
    text = capsys.readouterr().out
    assert "--adopt PATH.zip --name NAME" in text and "--restore-sidecar" in text
    named = [p for p in re.findall(r"archive/[\w./-]+\.zip", text) if "NAME" not in p]
    assert named and all((ROOT / p).is_file() for p in named), named


@pytest.mark.parametrize("cmd", [
    [sys.executable, "-m", "panda_lead.cli.run", "--help"],
    [sys.executable, "-m", "panda_lead", "--help"],
    [sys.executable, str(ROOT / "env.py"), "--help"],
], ids=["python -m panda_lead.cli.run", "python -m panda_lead", "env.py"])
def test_module_and_script_help_prints_help(cmd):
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("usage: ")


def test_env_script_prints_the_manual():
    out = run_script("env.py")
    assert out.returncode == 0 and "## Observation space" in out.stdout


def test_adopt_refuses_an_existing_name_naming_the_name_flag(monkeypatch):
    """The refusal used to tell eval.py --adopt's user to choose another --archive name."""
    from panda_lead.adopt import adopt

    monkeypatch.chdir(ROOT)  # archive/indep_v5 exists here
    with pytest.raises(UserError, match=r"indep_v5.zip exists; choose another --name name"):
        adopt(ROOT / "no_such_model.zip", "indep_v5")


def test_trains_next_commands_use_a_prefix_unique_to_the_run(tmp_path, capsys):
    from types import SimpleNamespace

    from panda_lead.training import loop

    tracker = SimpleNamespace(best_step=None)
    clock = SimpleNamespace(elapsed=lambda: 1.0)
    prefixes = []
    for name in ("lead__0__1700000000", "lead__0__1700000100"):
        loop._summary(tmp_path / name, tracker, 10, tmp_path / name / "final_model.zip", clock)
        line = next(ln for ln in capsys.readouterr().out.splitlines() if "eval.py" in ln)
        prefixes.append(re.search(r"--prefix (\S+)", line).group(1))
    assert prefixes == ["lead__0__1700000000", "lead__0__1700000100"]  # was "lead" twice
