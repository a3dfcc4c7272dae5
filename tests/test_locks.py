"""Two commands on one thing at once (issue 25): a run folder still training, an archive name,
a run name in the same second. The second is refused in one line, or gets its own folder;
never do two interleave their files. Tests wait for events, never for a time budget."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from conftest import PipeLines, run_in_process

from panda_lead.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MUJOCO_GL": "egl"}
TINY = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
        "--n-workers", "1", "--no-progress"]


def run(script, *args, cwd, timeout=None):
    """train.py in-process (conftest.run_in_process); the run it meets is a real process."""
    return run_in_process(script, *args, cwd=cwd)


def test_a_second_resume_of_a_run_still_training_is_refused(tmp_path):
    """Item 5: the run folder is locked (flock on RUN/.lock) while it trains; a second
    `--resume` of it is one line naming the holder, and the run it would have joined goes on."""
    cmd = [sys.executable, str(ROOT / "train.py"), "--timesteps", "100000000", "--eval-freq",
           "0", "--checkpoint-freq", "128", "--runs-dir", str(tmp_path / "runs"), *TINY]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env=ENV)
    out = PipeLines(proc.stdout)
    PipeLines(proc.stderr)
    try:
        out.wait_for("training started")
        (run_dir,) = (tmp_path / "runs").iterdir()
        before = sorted(p.name for p in run_dir.iterdir())
        second = run(ROOT / "train.py", "--resume", run_dir, "--no-progress", cwd=tmp_path)
        assert second.returncode == 2, second.stderr
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1, second.stderr
        assert lines[0] == (f"error: {run_dir}: the run folder is in use by another process "
                            f"(pid {proc.pid}); wait for it to finish")
        assert proc.poll() is None  # the first run trains on
        after = {p.name for p in run_dir.iterdir()}
        assert set(before) <= after and not after & {"interrupted_model.zip", "final_model.zip"}
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.fixture
def run_with_a_model(tmp_path):
    """A run folder holding a best_model pair (an untrained PPO, saved as the loop saves)."""
    from stable_baselines3 import PPO

    from panda_lead.env import PandaLeadEnv
    from panda_lead.models import save_model

    run_dir = tmp_path / "runs" / "r"
    e = PandaLeadEnv()
    model = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu",
                policy_kwargs={"net_arch": [16, 16]})
    save_model(model, run_dir / "best_model.zip", {"env_config": e.config, "train_config": {},
                                                   "timesteps": 64})
    return run_dir


def test_two_runs_archiving_one_name_at_once_archive_it_once(run_with_a_model, tmp_path,
                                                             monkeypatch):
    """Item 7: both used to pass the "is archive/NAME free?" check, then both wrote and both
    printed "archived". Here two threads are held at a barrier right before the check-and-
    write (after their evaluations, stubbed out: they decide nothing about the lock), then
    released together: exactly one archives, the other is one UserError line."""
    from panda_lead.training import archive as archive_module

    monkeypatch.chdir(tmp_path)
    barrier = threading.Barrier(2, timeout=600)  # a hang guard, not a budget
    monkeypatch.setattr(archive_module, "evaluate", lambda *a, **k: {"mean_error_cm": 1.0,
                                                                       "in_band_pct": 50.0})

    def card_number(zip_path, policy=None, env_config=None):
        barrier.wait()  # both threads are past loading and about to take the name
        return 1.0

    monkeypatch.setattr(archive_module, "pinned_card_number", card_number)
    results: dict[int, object] = {}

    def archive(i: int) -> None:
        try:
            results[i] = archive_module.archive_model(run_with_a_model, "same")
        except UserError as exc:
            results[i] = exc

    threads = [threading.Thread(target=archive, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=600)
    won = [r for r in results.values() if isinstance(r, Path)]
    lost = [r for r in results.values() if isinstance(r, UserError)]
    assert len(won) == 1 and len(lost) == 1, results
    message = str(lost[0])
    assert "\n" not in message
    assert ("the archive name same is in use by another process" in message
            or "archive/same.zip exists" in message), message
    from panda_lead.models import verify

    side = verify(tmp_path / "archive" / "same.zip")
    assert side["name"] == "same" and (tmp_path / "archive" / "same.md").is_file()
    # and afterwards, a third run is refused by the plain check, before training
    out = run(ROOT / "train.py", "--archive", "same", "--timesteps", "10", cwd=tmp_path)
    assert out.returncode == 2 and "archive/same.zip exists" in out.stderr


def test_two_runs_started_in_the_same_second_get_their_own_folders(tmp_path, monkeypatch):
    """Item 25: runs/<name>__<seed>__<unix time> collided for two runs with the same --name
    and --seed in one second; the second now gets a counter suffix (mkdir is the claim, so
    the race is decided by the file system)."""
    from panda_lead.training import loop

    monkeypatch.setattr(loop.time, "time", lambda: 1_800_000_000.5)  # one frozen second
    runs = tmp_path / "runs"
    made = []

    def start():
        made.append(loop._new_run_dir(runs, "x", 7))

    threads = [threading.Thread(target=start) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=600)
    names = sorted(p.name for p in made)
    assert names == ["x__7__1800000000", "x__7__1800000000_1", "x__7__1800000000_2",
                     "x__7__1800000000_3"]
    assert sorted(p.name for p in runs.iterdir()) == names
