"""studies/rederive.py: a committed run summary is retrained from its config and seed, and its
evaluation curve is compared point by point."""

from __future__ import annotations

import importlib.util
import json
import sys

import pytest
from conftest import ROOT, one_line, run_script

from panda_lead.errors import UserError
from panda_lead.training.config import TrainConfig

# A run small enough for a test: three evaluations of 10-step episodes, 32 steps apart.
TINY = TrainConfig(timesteps=96, n_envs=2, n_steps=16, batch_size=32, n_epochs=1,
                   eval_freq=32, eval_steps=10, curriculum_steps=0, seed=7, n_workers=1)


@pytest.fixture
def rederive(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("rederive_study",
                                                  ROOT / "studies" / "rederive.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "RUNS_DIR", tmp_path / "summaries")
    return module


def write_summary(module, study, config: dict, curve, cpu=None) -> None:
    folder = module.RUNS_DIR / study
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"seed_{config['seed']}.json").write_text(json.dumps(
        {"train_config": config, "eval_curve": curve, "commit": "test", "cpu": cpu}))


def test_a_run_re_derives_and_a_changed_point_is_caught(rederive, tmp_path, capsys):
    curve = rederive.rerun_curve(TINY.to_dict(), evals=3, runs_dir=tmp_path / "first")
    assert [s for s, _ in curve] == [32, 64, 96]
    write_summary(rederive, "tiny", TINY.to_dict(), curve)
    assert rederive.main(rederive.Args(study="tiny", seed=7, evals=2)) == 0
    out = capsys.readouterr().out
    assert "re-derived: every point equal" in out and "differs" not in out
    assert "this CPU: " in out

    edited = [list(p) for p in curve]
    edited[1][1] += 0.01  # the second evaluation, as if the run had gone elsewhere
    write_summary(rederive, "tiny", TINY.to_dict(), edited, cpu="A CPU of another family")
    assert rederive.main(rederive.Args(study="tiny", seed=7, evals=2)) == 1
    out = capsys.readouterr().out
    assert "on A CPU of another family" in out and "it trained on another CPU" in out
    rows = {line.split("|")[1].strip(): line for line in out.splitlines() if line.startswith("| ")}
    assert "differs" not in rows["32"] and "differs" in rows["64"] and "-0.0100" in rows["64"]


@pytest.mark.parametrize("content, words", [
    ("{not json", "not a run summary"),
    ('{"train_config": [], "eval_curve": []}', "not a run summary"),
    ('{"train_config": {"seed": 3}, "eval_curve": [[1, 2.0]]}', "seed 3, not 7"),
])
def test_a_damaged_summary_is_one_user_error(rederive, content, words):
    (rederive.RUNS_DIR / "s").mkdir(parents=True)
    (rederive.RUNS_DIR / "s" / "seed_7.json").write_text(content)
    with pytest.raises(UserError, match=words):
        rederive.load_summary("s", 7)


def test_an_unknown_study_or_too_many_evaluations_is_one_line():
    one_line(run_script("studies/rederive.py", "--study", "no_such_study", "--seed", "1"),
             "no summary", "no_such_study")
    one_line(run_script("studies/rederive.py", "--study", "v5", "--seed", "1", "--evals", "999"),
             "fewer than --evals 999")


def test_a_rerun_that_stopped_early_has_not_re_derived(rederive):
    table, same = rederive.compare([(32, 5.0), (64, 4.0)], [(32, 5.0)])
    assert not same and "| 64 | 4.0000 | (none) | **missing** |" in table
    assert rederive.compare([(32, 5.0), (64, 4.0)], [(32, 5.0), (64, 4.0)])[1]
