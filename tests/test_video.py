"""Videos: what a panel says, the frames it draws, and that a failed write keeps the old file."""

from __future__ import annotations

import errno
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, run_script

from panda_lead import controllers, video
from panda_lead.cli import run as controller_cli
from panda_lead.env import PandaLeadEnv
from panda_lead.errors import UserError
from panda_lead.rollout import record

EGL = {"MUJOCO_GL": "egl"}


@pytest.fixture(scope="module")
def episode():
    """A 0.2 s analytic-lead episode and the model it ran on (20 rows, 10 frames at 50 fps)."""
    e = PandaLeadEnv(episode_steps=20)
    r = record(e, controllers.make_analytic(0.05), 3, "circle",
               {"controller": "analytic", "tau": 0.05, "model": None})
    return r, e.core.model


def _args(*argv):
    import tyro

    return tyro.cli(controller_cli.Args, args=list(argv),
                    default=controller_cli.Args(controller="policy"))


@pytest.mark.parametrize("argv,pair", [
    (["--compare"], ("classical", "policy")),
    (["--compare", "--controller", "analytic"], ("classical", "analytic")),
    (["--compare", "--controller", "classical"], ("classical", "policy")),
    (["--compare", "analytic", "policy"], ("analytic", "policy")),
    (["--compare", "classical", "analytic"], ("classical", "analytic")),
    ([], None),
])
def test_compare_takes_any_two_controllers(argv, pair):
    assert controller_cli.compare_pair(_args(*argv)) == pair


def test_compare_needs_two_names_and_a_video():
    with pytest.raises(UserError, match="two controllers"):
        controller_cli._validate(_args("--compare", "analytic", "--video", "x.mp4"))
    with pytest.raises(UserError, match="add --video"):
        controller_cli._validate(_args("--compare"))


@pytest.mark.parametrize("meta,expected", [
    ({"controller": "classical"}, "classical IK+PD (no lead)"),
    ({"controller": "analytic", "tau": 0.05}, "analytic lead, tau 0.05 s"),
    ({"controller": "policy", "model": "archive/best.zip"}, "policy lead (best)"),
    ({"controller": "policy", "model": "archive/best.zip", "env": {"follow_plan": True}},
     "policy lead (best) + plan"),
    ({"controller": "analytic", "tau": 0.04, "env": {"follow_plan": False}},
     "analytic lead, tau 0.04 s"),
])
def test_panels_are_labelled_by_what_drove_them(meta, expected):
    assert video.describe(meta) == expected


def test_compare_with_analytic_is_not_called_policy(tmp_path):
    """Regression: `eval.py --compare --controller analytic` labelled the analytic lead
    "RL lead" and printed "policy". Both sides come from the rollouts' own meta now."""
    out = run_script("eval.py", "--seed", "3", "--duration", "0.1", "--compare",
                     "--controller", "analytic", "--video", tmp_path / "c.mp4", env=EGL)
    assert out.returncode == 0, out.stderr
    assert "classical" in out.stdout and "analytic" in out.stdout
    assert "policy" not in out.stdout and "RL" not in out.stdout
    import imageio.v2 as imageio

    frames = imageio.mimread(tmp_path / "c.mp4")
    assert len(frames) == 5 and frames[0].shape == (480, 1280, 3)


def test_camera_frames_the_arm_and_the_path(episode):
    r, model = episode
    cam = video.fit_camera(model, [r], 4 / 3)
    # The arm reaches ~1 m: a camera fitted to it stands ~1-3 m off, not the 4 m of a
    # camera fitted to the whole floor.
    assert 0.8 < cam.distance < 3.0
    assert np.all(np.isfinite(cam.lookat))


def test_frames_show_the_arm_large_and_the_overlay(episode, tmp_path):
    r, model = episode
    video.write(tmp_path / "v.mp4", [r], model, progress=False)
    import imageio.v2 as imageio

    frames = imageio.mimread(tmp_path / "v.mp4")
    assert len(frames) == 10 and frames[0].shape == (480, 640, 3)
    f = frames[-1].astype(int)
    # The arm is white-grey; the floor and the sky are blue. A quarter of the frame's middle
    # band should be arm, where the old fixed camera gave a few percent.
    mid = f[60:420]
    whiteish = (mid.min(axis=2) > 150) & (np.ptp(mid, axis=2) < 40)
    assert whiteish.mean() > 0.08, whiteish.mean()
    # The top and bottom bars are darkened behind white text.
    assert f[:38].mean() < mid.mean() and f[:38].max() > 200


def test_a_long_title_leaves_the_clock_alone():
    """A side-by-side panel is 640 px wide; a model's long name once ran into the clock
    ("policy lead (v5_err_decay_wide_lr3e-4)t 3.02 s"). The clock's corner of the top bar must
    read the same with the long title as with none."""
    blank = np.zeros((480, 640, 3), np.uint8)
    alone = video.overlay(blank.copy(), "", 3.02, 0.01, 0.02)
    titled = video.overlay(blank.copy(), "policy lead (v5_err_decay_wide_lr3e-4)", 3.02, 0.01, 0.02)
    lit = np.flatnonzero(alone[:38].max(axis=(0, 2)) > 0)  # the clock's columns
    corner = slice(lit.min() - 8, 640)
    assert (titled[:38, corner] == alone[:38, corner]).all()
    assert titled[:38, :lit.min() - 8].max() > 200  # ... and the title is still drawn


def test_a_failed_panel_holds_its_last_frame(episode, tmp_path):
    r, model = episode
    import dataclasses

    short = dataclasses.replace(r, **{k: getattr(r, k)[:10] for k in
                                      ("t", "ee_pos", "target_pos", "target_vel",
                                       "target_acc", "lead", "qpos", "qvel",
                                       "self_collision", "collision_depth", "reachable")},
                                meta={**r.meta, "failure": "self_collision"})
    video.write(tmp_path / "v.mp4", [r, short], model, progress=False)
    import imageio.v2 as imageio

    assert len(imageio.mimread(tmp_path / "v.mp4")) == 10


def _old_file(path):
    path.write_bytes(b"a good video from yesterday" * 1000)
    return path.read_bytes()


def test_full_disk_keeps_the_old_file(episode, tmp_path, monkeypatch):
    """ENOSPC in the middle of the frames: one clear error, the old video byte for byte, and
    no temporary file left beside it."""
    r, model = episode
    out = tmp_path / "v.mp4"
    before = _old_file(out)
    calls = []

    def full(self, frame):
        calls.append(1)
        if len(calls) == 4:
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(video.FfmpegWriter, "append", full)
    with pytest.raises(UserError, match="No space left on device.*(unchanged|intact)"):
        video.write(out, [r], model, progress=False)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_ffmpeg_failure_reaches_python(episode, tmp_path, monkeypatch):
    """ffmpeg failing at the end (as when the disk fills while it writes the index) used to
    pass silently: its exit status is checked now, and its message is in the error."""
    r, model = episode
    out = tmp_path / "v.mp4"
    before = _old_file(out)
    real = video.FfmpegWriter.__init__

    def dies(self, path, *a, **kw):
        real(self, path, *a, **kw)
        self._proc.kill()  # as if the disk filled: ffmpeg dies, the pipe breaks
    monkeypatch.setattr(video.FfmpegWriter, "__init__", dies)
    with pytest.raises(UserError, match="ffmpeg failed .*; the old file is unchanged"):
        video.write(out, [r], model, progress=False)
    assert out.read_bytes() == before


def _can_mount_tmpfs() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt"], capture_output=True)
    return probe.returncode == 0


@pytest.mark.skipif(not _can_mount_tmpfs(), reason="no user namespaces to mount a tmpfs")
def test_a_real_full_disk_through_the_cli(tmp_path):
    """A 160 kB tmpfs (a private mount in a user namespace) holding a 100 kB old video: the
    new one does not fit. The script exits 2 with one line and the old bytes survive."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    script = f"""
set -e
mount -t tmpfs -o size=160k tmpfs {mnt}
head -c 100000 /dev/urandom > {mnt}/v.mp4
cp {mnt}/v.mp4 {tmp_path}/old.mp4
set +e
MUJOCO_GL=egl {sys.executable} {ROOT}/eval.py --seed 3 --duration 1 --controller analytic --force \\
    --video {mnt}/v.mp4 2> {tmp_path}/stderr
echo $? > {tmp_path}/rc
cmp {mnt}/v.mp4 {tmp_path}/old.mp4 && echo same > {tmp_path}/same
ls -a {mnt} > {tmp_path}/ls
"""
    subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", script],
                   check=True, timeout=300)
    stderr = (tmp_path / "stderr").read_text()
    assert (tmp_path / "rc").read_text().strip() == "2", stderr
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "the old file is unchanged" in errors[0], stderr
    assert "Traceback" not in stderr
    assert (tmp_path / "same").exists()
    assert (tmp_path / "ls").read_text().split() == [".", "..", "v.mp4"]
