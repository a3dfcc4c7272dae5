"""The evaluation harness: what an evaluation inherits from a model and what it does not."""

from __future__ import annotations

import numpy as np

from panda_lead import harness
from panda_lead.rollout import iter_record
from panda_lead.task import LeadTask

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def test_a_study_level_replaces_a_models_own_randomisation():
    """Regression (issue 22): archive/delayed.json trains with random 0-3 step delays; at a
    study's "3 steps" it kept random_delay and so saw 0-3 steps while the baselines saw 3."""
    level = {"obs_delay": 3, "action_delay": 3, "random_delay": False}
    ctrl = harness.build("policy", 50, ROOT / "archive/delayed.zip", level)
    assert ctrl.config.random_delay is False and ctrl.config.obs_delay == 3
    task = LeadTask(ctrl.config, 16, nthread=1)
    task.reset(None, list(range(16)))
    assert set(task.obs_delay) == {3} and set(task.action_delay) == {3}
    # With no level at all, the model's training delays are not inherited either.
    plain = harness.build("policy", 50, ROOT / "archive/delayed.zip")
    assert plain.config.obs_delay == 0 and not plain.config.random_delay
    assert {"obs_delay", "action_delay", "random_delay"} <= set(plain.dropped)
    noisy = harness.build("policy", 50, ROOT / "archive/noisy.zip", {"obs_noise": {}})
    assert noisy.config.obs_noise == {}


def test_a_collision_terminating_model_is_evaluated_to_the_end():
    """Regression (issue 22): v6/v7 sidecars terminate on self-collision, and eval.py played
    them that way, so every episode in which they touched themselves ended early and was
    dropped. An evaluation plays every episode to its end."""
    ctrl = harness.build("policy", 300, ROOT / "archive/collision_v6.zip")
    assert ctrl.config.terminate_on_collision is False
    seeds = [int(s) for s in (ROOT / "results/collision_seeds.txt").read_text().split()[:8]]
    rollouts = list(iter_record(ctrl.config, ctrl.act, seeds, meta=ctrl.meta))
    assert all(len(r.t) == 300 and r.meta["failure"] is None for r in rollouts)
    touched = [r.seed for r in rollouts if np.any(r.self_collision)]
    assert touched  # these collide, yet run to the end
