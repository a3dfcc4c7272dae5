"""Issue 39's before/after tools: ttq.py's paired candidates and bench.py --update-pairs."""

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
