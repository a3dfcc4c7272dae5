"""studies/distill.py: the oracle's leads become (observation, action) pairs exactly, the
student's regression learns them, and the run's models load and act like any other."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies"))

import distill  # noqa: E402

from panda_lead import controllers  # noqa: E402
from panda_lead.ilc import ILCConfig, learn_leads  # noqa: E402
from panda_lead.models import load_policy  # noqa: E402
from panda_lead.rollout import record_many  # noqa: E402

SEEDS = [3_000_000, 3_000_001, 3_000_002]


def test_pairs_are_the_replayed_leads_and_the_observations_the_policy_sees():
    config = distill.student_config(steps=40)
    leads, history = learn_leads(config, SEEDS, None, ILCConfig(iterations=1),
                                 controllers.make_analytic())
    obs, act, errors, ok = distill.record_pairs(config, leads, SEEDS)
    assert ok.all() and obs.shape == (3, 40, 18) and act.shape == (3, 40, 3)
    np.testing.assert_array_equal(act, (leads * (1 / config.max_lead)).astype(np.float32))
    assert 100 * np.mean(errors) == pytest.approx(history[-1])
    # The observation before step k is what a policy acting at step k is handed: a recorder
    # around any controller sees the same rows.
    seen = {}

    def spy(o, task):
        seen.setdefault(int(task.core.step_count[0]), o.copy())
        return act[:, task.core.step_count[0]]

    record_many(config, spy, SEEDS)
    for k in (0, 1, 17, 39):
        np.testing.assert_array_equal(seen[k], obs[:, k])
    # The 15-D headline policy reads its own columns of the 18-D observation, same scales.
    cols = distill.column_picker(distill.EnvConfig(obs_features=distill.OBS_15), config)
    np.testing.assert_array_equal(cols, np.arange(15))


def test_a_tiny_run_fits_the_teacher_and_its_model_loads_and_acts(tmp_path):
    args = distill.Args(command="run", seed=1, rounds=2, first=4, per_round=3, steps=60,
                        ilc=ILCConfig(iterations=1), epochs=8, batch_size=64, val_frac=0.25,
                        runs_dir=tmp_path, summarize=False)
    run_dir = distill.run(args, log=lambda s: None)
    rounds = json.loads((run_dir / "rounds.json").read_text())["rounds"]
    assert [r["trajectories"] for r in rounds] == [4, 3]
    assert rounds[1]["first_seed"] == 3_000_004  # seed 1's slice, fresh trajectories per round
    for r in rounds:  # the student's predictions move towards the teacher's actions
        assert r["fit"][-1]["train_mse"] < 0.7 * r["fit"][0]["train_mse"]
        assert np.isfinite(r["fit"][-1]["val_mse"])
    assert rounds[1]["teacher_steps"] == (1 + 2) * (4 + 3) * 60
    for name in ("best_model.zip", "final_model.zip"):
        policy, env, side = load_policy(run_dir / name)
        assert env["obs_features"] == list(distill.STUDENT_FEATURES)
        assert side["policy"]["log_std_init"] == -3.0
        assert side["timesteps"] == rounds[-1]["teacher_steps"] or name == "best_model.zip"
        out = record_many(distill.student_config(steps=20), controllers.make_policy(policy),
                          [0])
        assert np.isfinite(out[0].error).all() and np.abs(out[0].lead).max() > 0
