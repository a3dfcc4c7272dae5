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
