"""The evaluation harness: what an evaluation inherits from a model and what it does not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from panda_lead import harness
from panda_lead.errors import UserError
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
    pool = ROOT / "results/studies/collision/collision_seeds.txt"
    seeds = [int(s) for s in pool.read_text().split()[:8]]
    rollouts = list(iter_record(ctrl.config, ctrl.act, seeds, meta=ctrl.meta))
    assert all(len(r.t) == 300 and r.meta["failure"] is None for r in rollouts)
    touched = [r.seed for r in rollouts if np.any(r.self_collision)]
    assert touched  # these collide, yet run to the end


# --- issue 25, items 11, 13 and 18: one identity rule, streamed sets, contradicting flags -----

def _ikpd(tmp_path, *args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, str(ROOT / "ikpd.py"), *map(str, args)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)


def test_one_model_given_by_two_paths_is_one_set_and_two_taus_are_two(tmp_path):
    """Item 11: the same model given once by absolute path was refused as "mixes 2
    controllers", while a set mixing tau 0.04 and 0.08 was accepted. In process, through the
    writer eval.py and ikpd.py call (the command line's own refusal: test_reliability.py)."""
    import pytest

    from panda_lead.errors import UserError

    model = ROOT / "archive" / "indep_v5.zip"
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "indep_v5.zip").symlink_to(model)
    (tmp_path / "m" / "indep_v5.json").symlink_to(model.with_suffix(".json"))
    quiet = dict(echo=lambda _: None)
    for seed, path in ((0, model), (1, tmp_path / "m" / "indep_v5.zip")):
        harness.write_set(harness.build("policy", 5, path), [seed], None, tmp_path, "p", **quiet)
    assert len(list((tmp_path / "p").glob("*.npz"))) == 2  # one set: the same model's hash
    harness.write_set(harness.build("analytic", 5, tau=0.04), [0], None, tmp_path, "a", **quiet)
    with pytest.raises(UserError, match="another controller, model, setting or env"):
        harness.write_set(harness.build("analytic", 5, tau=0.08), [1], None, tmp_path, "a",
                          **quiet)
    assert len(list((tmp_path / "a").glob("*.npz"))) == 1


def test_a_set_is_written_as_episodes_finish_not_all_at_the_end(tmp_path, monkeypatch):
    """Item 13: every episode was kept in memory and nothing written until all had played.
    While the last batch plays, the files of the earlier batches are already on disk."""
    ctrl = harness.build("classical", 5)
    on_disk_while_playing = []

    def small_batches(config, act, seeds, shapes, meta, **kw):  # 2 episodes per batch
        def watching(*a, **k):
            on_disk_while_playing.append(len(list((tmp_path / "s").glob("*.npz"))))
            return act(*a, **k)
        return iter_record(config, watching, seeds, shapes, meta, batch_size=2)

    monkeypatch.setattr(harness, "iter_record", small_batches)
    assert harness.write_set(ctrl, [0, 1, 2, 3, 4], None, tmp_path, "s", echo=lambda _: None) == 5
    assert sorted(set(on_disk_while_playing)) == [0, 2, 4]  # batch 1, 2, 3


def test_an_interrupted_set_keeps_the_episodes_it_finished(tmp_path):
    """Item 13: Ctrl-C while writing a set was a traceback and lost everything; now the files
    already written stay (each complete) and the message says how many."""
    import pytest

    from panda_lead.errors import UserError

    ctrl = harness.build("classical", 5)
    lines = []

    def echo(line):
        lines.append(line)
        if len(lines) == 2:
            raise KeyboardInterrupt

    with pytest.raises(UserError, match="interrupted: 2 of 4 rollouts written"):
        harness.write_set(ctrl, [0, 1, 2, 3], None, tmp_path, "s", echo=echo)
    assert sorted(p.name for p in (tmp_path / "s").glob("*.npz")) == [
        "seed_0000.npz", "seed_0001.npz"]


def test_env_flags_that_contradict_the_model_are_refused_up_front(tmp_path):
    """Item 18: --env.action joint on a lead model crashed mid-episode. Refused when the
    controller is built, before anything plays; and through ikpd.py as one line."""
    import pytest

    from panda_lead.errors import UserError

    for flag in ({"action": "joint"}, {"obs_stack": 3}):
        with pytest.raises(UserError, match="contradicts the model"):
            harness.build("policy", 5, ROOT / "archive" / "indep_v5.zip", flag)
    out = _ikpd(tmp_path, "--controller", "policy", "--seeds", "0", "--prefix", "p",
                "--duration", "0.05", "--env.action", "joint")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "contradicts the model" in out.stderr
    assert not (tmp_path / "rollouts").exists()


def test_a_mapping_flag_changes_only_the_keys_given():
    """Issue 25 (also): --env.obs-noise target_vel 0.07 replaced a model's whole noise dict;
    it sets that one feature and keeps the others, as --env.ik.iters keeps the other IK knobs."""
    from panda_lead.config import EnvConfig

    model = EnvConfig(obs_noise={"target_vel": 0.1, "ee_pos": 0.01})
    assert model.merged({"obs_noise": {"target_vel": 0.07}}).obs_noise == {
        "target_vel": 0.07, "ee_pos": 0.01}
    ik = model.merged({"ik": {"iters": 2}}).ik
    assert ik.iters == 2 and ik.damping == model.ik.damping


def test_models_that_share_a_file_name_get_distinct_labels_or_a_user_error():
    # Each run's best model is best_model.zip: a study given five of them once drew one row
    # for all five (the last), silently.
    runs = [Path(f"sweeps/s/runs/t000{i}__{i}__9/best_model.zip") for i in range(3)]
    assert harness.model_labels(runs) == [f"t000{i}__{i}__9/best_model" for i in range(3)]
    assert harness.model_labels([Path("archive/a.zip"), runs[0]]) == ["a", "best_model"]
    with pytest.raises(UserError, match="share the label 't0000__0__9/best_model'"):
        harness.model_labels([runs[0], runs[0]])
