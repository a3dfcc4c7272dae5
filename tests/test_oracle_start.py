"""The oracle belongs to its starting model: its rollouts record the lead they started from,
and metrics.py refuses to read an oracle started from one model as another model's ceiling."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from panda_lead import rollout, trajectory
from panda_lead.errors import UserError
from panda_lead.harness import build
from panda_lead.ilc import ILCConfig, check_oracle_start, oracle_meta, oracle_start
from panda_lead.models import DEFAULT_MODEL, archived, load_policy
from panda_lead.rollout import Rollout

REPO = Path(__file__).resolve().parents[1]
SHA_X, SHA_Y = "a" * 64, "b" * 64


def offset_rollout(offset_m, seed, meta, T=60, dt=0.01):
    """The seed's own target (a rollout file must hold it), the tip offset_m away along x."""
    t = dt * np.arange(1, T + 1)
    target, vel, acc = trajectory.sample(seed, "circle").at(t)
    z3, z7 = np.zeros((T, 3)), np.zeros((T, 7))
    return Rollout(t=t, ee_pos=target + [offset_m, 0, 0], target_pos=target, target_vel=vel,
                   target_acc=acc, lead=z3, qpos=z7, qvel=z7, self_collision=np.zeros(T, bool),
                   collision_depth=np.zeros(T), reachable=np.ones(T, bool),
                   meta=dict(seed=seed, shape="circle", duration=T * dt, dt=dt, **meta))


def write(root, prefix, offset_m, meta, seeds=range(4)):
    for s in seeds:
        rollout.save(offset_rollout(offset_m, s, meta), rollout.rollout_path(prefix, s, root))


def oracle(sha, init="policy"):
    return {"controller": "ilc", "model_sha256": sha,
            "ilc": oracle_meta(ILCConfig(init=init), sha)}


def run_metrics(root, *args):
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    return subprocess.run([sys.executable, "metrics.py", "--root", str(root), "--prefix-a",
                           "analytic", "--prefix-b", "learned", *args, "--bootstrap", "200"],
                          cwd=REPO, capture_output=True, text=True, timeout=120, env=env)


def test_metrics_refuses_an_oracle_started_from_another_model(tmp_path):
    write(tmp_path, "analytic", 0.03, {"controller": "analytic", "tau": 0.04})
    write(tmp_path, "learned", 0.01, {"controller": "policy", "model_sha256": SHA_X})
    write(tmp_path, "oracle_x", 0.005, oracle(SHA_X))
    write(tmp_path, "oracle_y", 0.005, oracle(SHA_Y))
    p = run_metrics(tmp_path, "--oracle", "oracle_y")
    assert p.returncode == 2, p.stdout + p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), p.stderr
    assert SHA_Y[:12] in lines[0] and SHA_X[:12] in lines[0] and "rebuild" in lines[0]
    assert "captured" not in p.stdout
    p = run_metrics(tmp_path, "--oracle", "oracle_x")  # its own oracle: the share is printed
    assert p.returncode == 0, p.stderr
    assert "oracle 0.50 cm; captured 80% [80, 80]" in p.stdout  # (3 - 1) / (3 - 0.5)


def test_an_oracle_started_from_a_model_it_does_not_record_is_refused():
    old = {"controller": "ilc", "ilc": {"oracle": True, "init": "policy"}}  # no hash anywhere
    with pytest.raises(UserError, match="does not record"):
        check_oracle_start(old, {"B": {"controller": "policy", "model_sha256": SHA_X}}, "o")
    # An older file whose hash sits only in the rollout's model_sha256 still pairs with it.
    legacy = {"controller": "ilc", "model_sha256": SHA_X, "ilc": {"oracle": True,
                                                                  "init": "policy"}}
    assert oracle_start(legacy) == ("policy", SHA_X)
    check_oracle_start(legacy, {"B": {"controller": "policy", "model_sha256": SHA_X}}, "o")
    # An oracle started from the analytic lead belongs to no model.
    check_oracle_start(oracle(None, "analytic"),
                       {"B": {"controller": "policy", "model_sha256": SHA_Y}}, "o")


def test_the_built_oracle_records_its_starting_models_hash():
    _, _, side = load_policy(archived(DEFAULT_MODEL))
    ctrl = build("ilc", steps=10, ilc=ILCConfig(iterations=0))
    assert ctrl.meta["ilc"]["start_model_sha256"] == side["model_sha256"]
    assert oracle_start(ctrl.meta) == ("policy", side["model_sha256"])
    analytic_start = build("ilc", steps=10, ilc=ILCConfig(iterations=0, init="analytic"))
    assert oracle_start(analytic_start.meta) == ("analytic", None)


def test_an_oracle_belongs_to_its_starts_online_correction_too():
    """The same model with a lap-to-lap correction on top (panda_lead/online.py) is another
    lead: the oracle restarted from the model alone is not its ceiling, nor the other way."""
    rc = {"kind": "repetitive", "gain": 0.3, "advance": 15, "smooth": 0, "start": 0.5}
    plain_oracle = {"controller": "ilc", "ilc": oracle_meta(ILCConfig(), SHA_X)}
    rc_oracle = {"controller": "ilc", "ilc": oracle_meta(ILCConfig(), SHA_X, rc)}
    corrected = {"controller": "policy", "model_sha256": SHA_X, "online": rc}
    plain = {"controller": "policy", "model_sha256": SHA_X}
    with pytest.raises(UserError, match="no online correction.*repetitive correction"):
        check_oracle_start(plain_oracle, {"A": {"controller": "analytic"}, "B": corrected}, "o")
    with pytest.raises(UserError, match="repetitive correction.*no online correction"):
        check_oracle_start(rc_oracle, {"A": {"controller": "analytic"}, "B": plain}, "o")
    check_oracle_start(rc_oracle, {"A": {"controller": "analytic"}, "B": corrected}, "o")
    check_oracle_start(plain_oracle, {"A": {"controller": "analytic"}, "B": plain}, "o")


def test_an_oracle_belongs_to_its_starts_planner_hand_too():
    """A start run with the planner's hand (EnvConfig.follow_plan) is another controller: on
    the episodes the plan holds the lead is ignored, so that oracle is no ceiling for the same
    model without the hand, nor the other way."""
    hand_oracle = {"controller": "ilc", "ilc": oracle_meta(ILCConfig(), SHA_X, None, True)}
    plain_oracle = {"controller": "ilc", "ilc": oracle_meta(ILCConfig(), SHA_X)}
    handed = {"controller": "policy", "model_sha256": SHA_X, "env": {"follow_plan": True}}
    plain = {"controller": "policy", "model_sha256": SHA_X, "env": {"follow_plan": False}}
    analytic = {"controller": "analytic"}
    with pytest.raises(UserError, match="with the planner's hand, on the plain IK, B runs it "
                                        "without"):
        check_oracle_start(hand_oracle, {"A": analytic, "B": plain}, "o")
    with pytest.raises(UserError, match="without the planner's hand, on the plain IK, B runs "
                                        "it with.*--follow-plan"):
        check_oracle_start(plain_oracle, {"A": analytic, "B": handed}, "o")
    check_oracle_start(hand_oracle, {"A": analytic, "B": handed}, "o")
    check_oracle_start(plain_oracle, {"A": analytic, "B": plain}, "o")
    check_oracle_start(plain_oracle, {"A": analytic, "B": {"controller": "policy",
                                                           "model_sha256": SHA_X}}, "o")


def test_an_oracle_belongs_to_its_starts_ik_too():
    """A start on the collision-aware IK (--clearance) is another controller: its oracle is no
    ceiling for the same model on the plain IK, nor the other way, nor for another clearance."""
    clear_oracle = {"controller": "ilc", "ilc": oracle_meta(ILCConfig(), SHA_X, None, True, 0.03)}
    def on(clearance):
        return {"controller": "policy", "model_sha256": SHA_X,
                "env": {"follow_plan": True, "ik": {"clearance": clearance}}}
    analytic = {"controller": "analytic"}
    check_oracle_start(clear_oracle, {"A": analytic, "B": on(0.03)}, "o")
    with pytest.raises(UserError, match=r"collision-aware IK \(0.03 m\), B runs it with the "
                                        "planner's hand, on the plain IK"):
        check_oracle_start(clear_oracle, {"A": analytic, "B": on(0.0)}, "o")
    with pytest.raises(UserError, match="--follow-plan --clearance 0.02"):
        check_oracle_start(clear_oracle, {"A": analytic, "B": on(0.02)}, "o")


def test_the_oracle_with_the_hand_replays_with_it_and_says_so():
    """online_correction.py play --oracle --follow-plan (--clearance): the start and every
    replay run with the hand (on the collision-aware IK), and the oracle's files record it
    (what metrics.py's check reads)."""
    sys.path.insert(0, str(REPO / "studies"))
    from online_correction import Args, _oracle

    from panda_lead.online import OnlineCorrection

    correction = OnlineCorrection("repetitive", 0.5, 10, 3, fade=0.1)
    for hand, clearance in ((False, 0.0), (True, 0.0), (True, 0.03)):
        ctrl = _oracle(Args(command="play", follow_plan=hand, clearance=clearance, oracle=True),
                       correction)
        assert ctrl.config.follow_plan is hand and ctrl.init_config.follow_plan is hand
        assert ctrl.config.ik.clearance == ctrl.init_config.ik.clearance == clearance
        assert bool(ctrl.meta["ilc"].get("start_follow_plan")) is hand
        assert ctrl.meta["ilc"].get("start_clearance", 0.0) == clearance
        assert ctrl.meta["ilc"]["start_online"] == correction.meta()


def test_a_studys_share_pairs_each_seed_with_its_own_oracle():
    """metrics.stats.two_level_share: the point value is the share of the means, and a seed is
    drawn with its own ceiling: a study whose every seed reaches its own ceiling captures 100%
    exactly, however far apart the seeds' ceilings lie (drawn apart, the CI would widen)."""
    from panda_lead.metrics.stats import two_level_share

    rng = np.random.default_rng(0)
    base = np.full(50, 3.0)
    share, ci = two_level_share(base, np.full((3, 50), 1.0), np.full((3, 50), 0.5), 500, rng)
    assert share == pytest.approx(0.8) and ci == pytest.approx((0.8, 0.8))
    ceilings = np.array([[0.2], [1.0], [2.0]]) + rng.uniform(0, 0.1, (3, 50))
    share, ci = two_level_share(base, ceilings.copy(), ceilings, 500, rng)
    assert share == pytest.approx(1.0) and ci == pytest.approx((1.0, 1.0))
    with pytest.raises(ValueError, match="do not pair"):
        two_level_share(base, np.ones((3, 50)), np.ones((2, 50)), 10, rng)


def test_oracle_share_prints_the_studys_share_and_refuses_a_foreign_oracle(tmp_path, capsys):
    """studies/oracle_share.py: each seed's set against its own oracle, and the study's share;
    an oracle started from another model is refused as metrics.py refuses it."""
    sys.path.insert(0, str(REPO / "studies"))
    import oracle_share

    write(tmp_path, "analytic", 0.03, {"controller": "analytic", "tau": 0.04})
    for k, sha in ((1, SHA_X), (2, SHA_Y)):
        write(tmp_path, f"lead{k}", 0.01, {"controller": "policy", "model_sha256": sha})
        write(tmp_path, f"oracle{k}", 0.005, oracle(sha))
    args = oracle_share.Args(pairs=["lead1:oracle1", "lead2:oracle2"], root=tmp_path,
                             bootstrap=200)
    oracle_share.main(args)
    out = capsys.readouterr().out
    assert "| lead2 | oracle2 | 1.00 / 0.50 | 80% | 1.00 / 0.50 | 80% |" in out
    assert out.count("captured **80% [80, 80]**") == 2  # (3 - 1) / (3 - 0.5), mean and settled
    with pytest.raises(UserError, match="rebuild"):
        oracle_share.main(oracle_share.Args(pairs=["lead1:oracle2"], root=tmp_path))
    with pytest.raises(UserError, match="not an ILC oracle"):
        oracle_share.main(oracle_share.Args(pairs=["lead1:lead2"], root=tmp_path))
