"""Issue 39's before/after tools: ttq.py's paired candidates, bench.py --update-pairs and
--parallel-pairs."""

from __future__ import annotations

import pytest
from conftest import one_line, run_in_process, run_script


def test_an_unknown_ttq_candidate_is_one_line_before_any_training(tmp_path):
    out = run_in_process("studies/ttq.py", "--candidates", "default", "defualt",
                         "--runs-dir", tmp_path / "runs", cwd=tmp_path)
    one_line(out, "unknown candidate 'defualt'", "did you mean 'default'")
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_update_pairs_time_both_updates_on_whole_training_runs(tmp_path):
    out = run_script("studies/bench.py", "--update-pairs", "1", "--update-steps", "256",
                     cwd=tmp_path, env={"MUJOCO_GL": "egl"}, timeout=900)
    assert out.returncode == 0, out.stderr
    assert "pair 1: FastPPO" in out.stdout and "SB3's update" in out.stdout
    assert "median of 1 pairs: FastPPO" in out.stdout and "peak memory" in out.stdout


@pytest.mark.slow
def test_update_pairs_time_any_flags_against_the_defaults(tmp_path):
    out = run_script("studies/bench.py", "--update-pairs", "1", "--update-steps", "256",
                     "--update-base=--n-envs 2 --n-steps 64 --batch-size 64",
                     "--update-against=--batch-size 128", cwd=tmp_path,
                     env={"MUJOCO_GL": "egl"}, timeout=900)
    assert out.returncode == 0, out.stderr
    assert "pair 1: defaults (--n-envs 2 --n-steps 64 --batch-size 64)" in out.stdout
    assert "samples/s" in out.stdout and "--batch-size 128 " in out.stdout
    assert "median of 1 pairs: defaults" in out.stdout


@pytest.mark.slow
def test_parallel_pairs_time_one_run_and_several_at_once(tmp_path):
    out = run_script("studies/bench.py", "--parallel-pairs", "1", "--parallel-runs", "2",
                     "--update-steps", "256", "--parallel-flags=--n-envs 2 --n-steps 64",
                     cwd=tmp_path, env={"MUJOCO_GL": "egl"}, timeout=900)
    assert out.returncode == 0, out.stderr
    assert "pair 1: one run" in out.stdout and "2 at once" in out.stdout
    assert "median of 1 pairs: 2 runs at once give" in out.stdout
    assert "flags: --n-envs 2 --n-steps 64" in out.stdout
    assert not list(tmp_path.iterdir())  # the runs' folders went with their temporary folder


def _run_device_plan(tmp_path, *flags: str) -> None:
    """studies/device_plan.py with these flags, every process it started reaped whatever
    happens; asserts it succeeded."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    import psutil

    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, str(root / "studies/device_plan.py"), *flags, "--out",
           str(tmp_path / "out")]
    seen: dict[int, psutil.Process] = {}  # every descendant: each step runs in its own session,
    # out of reach of a kill of the plan's group, so they are reaped one by one below
    with open(tmp_path / "stderr", "w") as err:
        plan = subprocess.Popen(cmd, cwd=tmp_path, env={**os.environ, "MUJOCO_GL": "egl"},
                                stdout=subprocess.DEVNULL, stderr=err)
        try:
            start = time.monotonic()  # a hang guard, not a speed limit: a plan takes minutes
            while plan.poll() is None and time.monotonic() - start < 1500:
                try:
                    for child in psutil.Process(plan.pid).children(recursive=True):
                        seen.setdefault(child.pid, child)
                except psutil.Error:
                    pass  # a child that ended between the listing and the read
                time.sleep(0.5)
        finally:
            if plan.poll() is None:
                plan.kill()
            for proc in seen.values():  # psutil checks each is still the process it saw
                try:
                    proc.kill()
                except psutil.Error:
                    pass  # already gone
            plan.wait()
    assert plan.returncode == 0, (tmp_path / "stderr").read_text()[-3000:]


@pytest.mark.slow
def test_the_device_plan_dry_runs_every_step_and_writes_one_table(tmp_path):
    # studies/device_plan.py is what ran on the lent H100 machine (issue 41); --small runs every
    # step here on the CPU with tiny budgets (about 6 minutes on 2 cores).
    import json
    import tarfile
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    _run_device_plan(tmp_path, "--small")
    table = (tmp_path / "out" / "table.md").read_text()
    assert "`--device cpu` end to end" in table and "| ok |" in table
    assert "physics-bound limit" in table and "batched env, 256 envs, 2 threads" in table
    assert table.count("PPO samples/s, ") == 7 and "no figure" not in table.split("quality")[0]
    assert table.count("(finished, ") == 2
    with tarfile.open(tmp_path / "out" / "artifacts.tar.gz") as tar:
        names = tar.getnames()
        side = json.load(tar.extractfile("archive/cpu_e2e.json"))
    assert side["name"] == "cpu_e2e" and side["train_config"]["device"] == "cpu"
    assert "=== e2e_resume_archive: exit 0" in (tmp_path / "out" / "log.txt").read_text()
    assert "archive/cpu_e2e.zip" in names and "quality_s2/best_model.zip" in names
    assert not list((root / "archive").glob("cpu_e2e.*"))  # a dry run leaves the archive as it was


@pytest.mark.slow
def test_the_device_plan_runs_named_variants_side_by_side_after_a_profile(tmp_path):
    # The second lease's call (2026-11-27): a cProfile first, then one run per variant at once.
    import json
    import tarfile

    _run_device_plan(tmp_path, "--small", "--quality-only", "--cprofile", "1",
                     "--quality-variants=--preset v5_err_decay --seed 3; --seed 4")
    table = (tmp_path / "out" / "table.md").read_text()
    assert "--preset v5_err_decay --seed 3 (evaluation set" in table
    assert "--seed 4 (evaluation set" in table and table.count("(finished, ") == 2
    assert "us wall per sample" in (tmp_path / "out" / "cprofile_gpu.txt").read_text()
    with tarfile.open(tmp_path / "out" / "artifacts.tar.gz") as tar:
        first = json.load(tar.extractfile("quality_v1/config.json"))
        second = json.load(tar.extractfile("quality_v2/config.json"))
    assert (first["preset"], first["seed"]) == ("v5_err_decay", 3)
    assert (second["preset"], second["seed"]) == (None, 4)


def test_the_device_plan_names_an_unknown_flag_in_one_line(tmp_path):
    out = run_in_process("studies/device_plan.py", "--quality-only", "--qualty-seeds", "3",
                     cwd=tmp_path)
    one_line(out, "--qualty-seeds")
    assert not list(tmp_path.iterdir())  # nothing written before the command line is read
