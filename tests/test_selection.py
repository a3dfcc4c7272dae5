"""The selection rule that does not wobble (issue 37): a selection set disjoint from every other
seed set, sized from a measured spread, and a tie rule that prefers the smoother of two
studies the set cannot separate."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from panda_lead import seeds

ROOT = Path(__file__).resolve().parents[1]

def _load(name: str):
    sys.path.insert(0, str(ROOT / "studies"))
    spec = importlib.util.spec_from_file_location(f"_test_{name}",
                                                  ROOT / "studies" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module

def test_the_selection_set_is_disjoint_from_training_tuning_test_and_every_other_set():
    select = set(seeds.SELECT_SEEDS)
    assert len(select) == seeds.SELECT_SIZE == len(seeds.SELECT_SEEDS)
    others = {"test": seeds.TEST_SEEDS, "eval": [s for s, _ in seeds.EVAL_SET],
              "tune": seeds.TUNE_SEEDS, "pool": seeds.POOL_SEEDS,
              "distill": seeds.DISTILL_SEEDS}
    for name, other in others.items():
        assert not select & set(other), name
    # training draws its trajectory seeds from [TRAIN_SEED_LOW, TRAIN_SEED_HIGH)
    assert max(select) < seeds.TRAIN_SEED_LOW

def test_the_size_grows_with_the_square_of_the_spread():
    selection = _load("selection")
    # (1.96 + 0.84)^2 = 7.85: a 0.05 cm spread needs 8 trajectories, ten times it 100 times more
    assert selection.size_for(0.05) == 8
    assert selection.size_for(0.5) == 785
    # and at that size a 0.05 cm difference is 2.8 standard errors from 0
    n = selection.size_for(0.5)
    assert 0.05 / (0.5 / np.sqrt(n)) >= 2.8

def test_tied_studies_rank_the_smoother_first_separated_ones_by_error():
    runs = _load("runs")
    rng = np.random.default_rng(0)
    base = rng.normal(2.0, 0.5, 400)
    errors = {"rough": base + rng.normal(0.0, 0.3, 400),  # level with "smooth" within noise
              "smooth": base + rng.normal(0.0, 0.3, 400),
              "worse": base + 0.5 + rng.normal(0.0, 0.3, 400)}  # clearly behind both
    errors["rough"] -= errors["rough"].mean() - errors["smooth"].mean() + 0.005  # 0.005 ahead
    jerks = {"rough": 900.0, "smooth": 500.0, "worse": 100.0}
    order = runs.tie_ranked(errors, jerks, n_boot=2000)
    assert [name for name, _ in order] == ["smooth", "rough", "worse"]
    assert [tied for _, tied in order] == [False, True, False]
    # Without the jerk difference the order is by error alone.
    jerks = {"rough": 500.0, "smooth": 900.0, "worse": 100.0}
    assert [n for n, _ in runs.tie_ranked(errors, jerks, n_boot=2000)] == ["rough", "smooth",
                                                                          "worse"]

def test_a_chain_of_ties_never_puts_a_study_above_one_clearly_better():
    """Ties are not transitive (A ~ B and B ~ C while C is clearly behind A). The rule only
    swaps two tied neighbours, the smoother up, so in the final order every pair ranked against
    its means is itself tied with the smoother above: never one the CI separates."""
    from panda_lead.metrics.stats import paired_ci

    runs = _load("runs")
    rng = np.random.default_rng(1)

    def near(base: np.ndarray, mean: float) -> np.ndarray:  # the base + noise, at this mean
        x = base + rng.normal(0.0, 0.2, len(base))
        return x - x.mean() + base.mean() + mean

    inverted = 0
    for _ in range(4):
        base = rng.normal(2.0, 0.5, 300)
        # six studies 0.015 cm apart (CI half-width ~0.03): neighbours tie, far ones do not
        errors = {f"s{k}": near(base, 0.015 * k) for k in range(6)}
        jerks = {name: float(rng.uniform(100, 1000)) for name in errors}
        order = [name for name, _ in runs.tie_ranked(errors, jerks, n_boot=500)]
        for i, upper in enumerate(order):
            for lower in order[i + 1:]:
                if errors[lower].mean() < errors[upper].mean():
                    inverted += 1
                    lo, hi = paired_ci(errors[lower] - errors[upper], 500, 0)
                    assert lo <= 0.0 <= hi and jerks[upper] < jerks[lower], (upper, lower)
    assert inverted  # the draws do rank some studies against their means
    # the chain itself: a ~ b, b ~ c, c clearly behind a and the smoothest: c stays behind a
    base = rng.normal(2.0, 0.5, 300)
    errors = {"a": near(base, 0.0), "b": near(base, 0.02), "c": near(base, 0.04)}
    assert paired_ci(errors["c"] - errors["a"], 500, 0)[0] > 0
    assert paired_ci(errors["b"] - errors["a"], 500, 0)[0] < 0
    assert paired_ci(errors["c"] - errors["b"], 500, 0)[0] < 0
    order = [n for n, _ in runs.tie_ranked(errors, {"a": 900.0, "b": 500.0, "c": 100.0},
                                           n_boot=500)]
    assert order.index("a") < order.index("c")

def test_a_model_that_knows_the_path_is_never_ranked_with_causal_ones(tmp_path, monkeypatch,
                                                                      capsys):
    """Issue 37: the preview variant is labelled and kept apart in every table. A preview model
    far ahead of two causal ones gets its own tables; the causal ones rank among themselves."""
    import json

    selection = _load("selection")
    monkeypatch.setattr(selection, "SCORES", tmp_path)
    span = [seeds.SELECT_SEEDS[0], seeds.SELECT_SEEDS[-1]]
    rng = np.random.default_rng(1)
    for name, level, knows in (("ahead", 0.5, True), ("causal_a", 2.0, False),
                               ("causal_b", 2.5, False)):
        errors = level + rng.normal(0.0, 0.1, 50)
        (tmp_path / f"{name}.json").write_text(json.dumps({
            "model": f"archive/{name}.zip", "seeds": span, "knows_path": knows,
            "mean_err_cm": errors.tolist(), "jerk_rms": [500.0] * 50}))
    selection.rank(selection.Args(command="rank"))
    out = capsys.readouterr().out
    causal, preview = out.split("Models, knows the planned path")
    assert "Models, causal" in causal
    assert "| 1 | causal_a |" in causal and "| 2 | causal_b |" in causal
    assert "ahead" not in causal
    assert "| 1 | ahead |" in preview
    assert "causal_a" not in preview and "causal_b" not in preview

def test_the_rank_tells_an_unscored_kept_seed_from_a_study_with_too_few_seeds(tmp_path,
                                                                              monkeypatch,
                                                                              capsys):
    """A study whose kept seed models are all scored but number under three is not "not yet
    scored" (the rank said so of deploy_real_5m's two scored seeds until 2026-11-27)."""
    import json

    selection = _load("selection")
    root, scores = tmp_path / "repo", tmp_path / "scores"
    scores.mkdir()
    (root / "archive" / "seeds").mkdir(parents=True)
    span = [seeds.SELECT_SEEDS[0], seeds.SELECT_SEEDS[-1]]
    for study, kept, scored in (("alpha", (1, 2), (1, 2)), ("beta", (1,), ())):
        (root / "results" / "runs" / study).mkdir(parents=True)
        (root / "results" / "runs" / study / "seed_1.json").write_text("{}")
        for k in kept:
            (root / "archive" / "seeds" / f"{study}_s{k}.zip").write_bytes(b"")
        for k in scored:
            (scores / f"{study}_s{k}.json").write_text(json.dumps({
                "model": f"archive/seeds/{study}_s{k}.zip", "seeds": span, "knows_path": False,
                "mean_err_cm": [2.0 + k / 10] * 20, "jerk_rms": [500.0] * 20}))
    monkeypatch.setattr(selection, "ROOT", root)
    monkeypatch.setattr(selection, "SCORES", scores)
    selection.rank(selection.Args(command="rank"))
    out = capsys.readouterr().out
    unscored = next(line for line in out.splitlines() if line.startswith("Kept but not yet"))
    few = next(line for line in out.splitlines() if line.startswith("Scored, fewer than 3"))
    assert "beta" in unscored and "alpha" not in unscored
    assert "alpha" in few and "beta" not in few

def test_choose_by_selection_takes_the_rules_first_seed_and_refuses_a_stale_score(
        tmp_path, monkeypatch):
    """`runs.py choose --by selection`: the seed issue 37's rule ranks first on the selection
    set (lower error; of two tied seeds the smoother), only from scores of the models kept now."""
    import json

    import pytest

    from panda_lead.errors import UserError

    runs = _load("runs")
    monkeypatch.chdir(tmp_path)
    kept, scores = tmp_path / "archive" / "seeds", tmp_path / "scores"
    kept.mkdir(parents=True)
    scores.mkdir()
    def put(seed: int, level: float, jerk: float, sha: str = "kept") -> None:
        noise = np.random.default_rng(seed).normal(0.0, 0.3, 400)  # each seed its own spread
        (kept / f"st_s{seed}.json").write_text(json.dumps({"model_sha256": f"{sha}{seed}"}))
        (scores / f"st_s{seed}.json").write_text(json.dumps({
            "model_sha256": f"kept{seed}", "mean_err_cm": (level + noise).tolist(),
            "jerk_rms": [jerk] * 400}))

    put(1, 2.6, 480.0)
    put(2, 2.4, 500.0)
    put(3, 2.9, 400.0)
    seeds_ = [{"seed": k} for k in (1, 2, 3)]
    assert runs.choose_by_selection("st", seeds_, scores)["seed"] == 2
    put(1, 2.41, 480.0)  # tied with seed 2 within the CI, and smoother: it ranks first
    assert runs.choose_by_selection("st", seeds_, scores)["seed"] == 1
    put(3, 2.9, 400.0, sha="retrained")  # the kept model changed after it was scored
    with pytest.raises(UserError, match="scored another model"):
        runs.choose_by_selection("st", seeds_, scores)
    (scores / "st_s3.json").unlink()
    with pytest.raises(UserError, match="not: st_s3"):
        runs.choose_by_selection("st", seeds_, scores)

def test_the_rank_counts_a_warm_started_models_starting_steps(tmp_path, monkeypatch):
    """A model trained on top of another (train.py --init-from) shows both budgets, so that a
    10M-step study is not read as a 5M one beside the rest."""
    import json

    selection = _load("selection")
    (tmp_path / "archive").mkdir()
    for name, steps, start in (("start", 5_000_000, None), ("warm", 2_500_000, "archive/start.zip"),
                               ("lost", 1_000_000, "archive/gone.zip")):
        side = {"train_config": {"timesteps": steps}, "env_config": {}}  # as a sidecar
        if start:
            side["init_from"] = {"path": start, "sha256": "0" * 64}
        (tmp_path / "archive" / f"{name}.json").write_text(json.dumps(side))
    monkeypatch.setattr(selection, "ROOT", tmp_path)
    assert selection._budget({"model": "archive/start.zip"}) == "5M"
    assert selection._budget({"model": "archive/warm.zip"}) == "5M + 2.5M"
    assert selection._budget({"model": "archive/lost.zip"}) == "? + 1M"
    assert selection._budget({"model": "archive/absent.zip"}) == ""

def test_a_table_names_the_set_its_seeds_come_from():
    """deploy.py's tables say which set they played (a table on selection seeds once called
    them test seeds): every seed of one set names it, a mix names none."""
    assert seeds.set_name(range(0, 100)) == "test"
    assert seeds.set_name(seeds.SELECT_SEEDS[:500]) == "selection"
    assert seeds.set_name(seeds.TUNE_SEEDS) == "tuning"
    assert seeds.set_name([s for s, _ in seeds.EVAL_SET]) == "evaluation"
    assert seeds.set_name([0, seeds.SELECT_SEEDS[0]]) == "trajectory"
    assert seeds.set_name([]) == "trajectory"


def test_the_headline_is_the_rules_pick_and_the_default_model(monkeypatch):
    """The README's headline follows the stated rule: the archived headline is the seed that
    `choose --by selection` picks from the committed scores of its study's kept seeds, it holds
    that seed's weights, and eval.py plays it by default (until 2026-11-27 the README named a
    model the rule no longer picked)."""
    import zipfile

    from panda_lead.models import DEFAULT_MODEL

    monkeypatch.chdir(ROOT)
    steps, runs = _load("results_steps"), _load("runs")
    assert steps.HEADLINE_STUDY in steps.BY_SELECTION
    assert DEFAULT_MODEL == steps.HEADLINE
    study = runs.load_study(steps.HEADLINE_STUDY, ("best",))
    chosen = runs.choose_by_selection(steps.HEADLINE_STUDY, study, runs.SELECTION_SCORES)
    assert steps.HEADLINE == f"{steps.HEADLINE_STUDY}_s{chosen['seed']}"
    with zipfile.ZipFile(ROOT / "archive" / f"{steps.HEADLINE}.zip") as a, \
            zipfile.ZipFile(runs.seed_path(steps.HEADLINE_STUDY, chosen["seed"])) as b:
        assert a.read("policy.pth") == b.read("policy.pth")
