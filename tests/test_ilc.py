"""The ILC oracle: a ceiling built from the same core, batched, and labelled as what it is."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from panda_lead import controllers
from panda_lead.config import EnvConfig
from panda_lead.errors import UserError
from panda_lead.ilc import ILCConfig, learn_leads, replay_controller
from panda_lead.rollout import record_many

ROOT = Path(__file__).resolve().parents[1]
CONFIG = EnvConfig(episode_steps=150)
SEEDS = [3, 11, 42, 800_001]


def test_replaying_a_controllers_own_leads_is_that_controller_bit_for_bit():
    """The oracle's replay is exact: with zero replays it returns the first replay's leads,
    and playing them back gives that controller's episodes bit for bit."""
    analytic = controllers.make_analytic()
    leads, history = learn_leads(CONFIG, SEEDS, None, ILCConfig(iterations=0), analytic)
    first = record_many(CONFIG, analytic, SEEDS)
    again = record_many(CONFIG, replay_controller(leads, SEEDS, CONFIG.max_lead), SEEDS)
    for a, b in zip(first, again, strict=True):
        assert np.array_equal(a.ee_pos, b.ee_pos) and np.array_equal(a.lead, b.lead)
    assert history == [pytest.approx(100 * np.mean([r.error.mean() for r in first]))]


def test_each_replay_keeps_only_improvements_and_the_error_falls():
    leads, history = learn_leads(CONFIG, SEEDS, None, ILCConfig(iterations=6),
                                 controllers.make_analytic())
    assert all(np.diff(history) <= 0)  # never worse: a worse replay is discarded per seed
    assert history[-1] < 0.8 * history[0]  # and it learns: the ceiling is below its start
    assert np.abs(leads).max() <= CONFIG.max_lead + 1e-12  # within the lead's bound
    final = record_many(CONFIG, replay_controller(leads, SEEDS, CONFIG.max_lead), SEEDS)
    assert 100 * np.mean([r.error.mean() for r in final]) == pytest.approx(history[-1])


def test_the_oracle_refuses_what_it_cannot_do():
    with pytest.raises(UserError, match="needs action 'lead'"):
        learn_leads(CONFIG.replace(action="joint"), SEEDS, None, ILCConfig(iterations=1),
                    controllers.classical)
    with pytest.raises(UserError, match="each trajectory seed once"):
        learn_leads(CONFIG, [1, 1], None, ILCConfig(iterations=1), controllers.classical)
    with pytest.raises(UserError, match="ilc.init must be one of"):
        ILCConfig(init="future")


def test_ikpd_writes_oracle_rollouts_labelled_as_an_oracle(tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / "ikpd.py"), "--controller", "ilc",
                          "--ilc.iterations", "2", "--seeds", "0-2", "--prefix", "ilc",
                          "--duration", "0.5"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert "ILC replay 2" in out.stdout
    files = sorted((tmp_path / "rollouts" / "ilc").glob("*.npz"))
    assert len(files) == 3
    meta = json.loads(str(np.load(files[0])["meta"]))
    assert meta["controller"] == "ilc" and meta["ilc"]["oracle"] is True
    assert meta["ilc"]["init"] == "policy" and meta["model_sha256"]  # started from the model
