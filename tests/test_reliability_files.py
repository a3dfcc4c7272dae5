"""Reliability round 4 (docs/reliability.md, "Round 4: files, resume, adopt"): what a rollout
file, a run folder, an archive name and an adopted model may hold, each defect of
../shared/RELIABILITY-4.md (and issue 38's review) reproduced in-process on files the repo's
own writers made in tmp_path."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from panda_lead import rollout
from panda_lead.errors import UserError
from panda_lead.rollout import RolloutError

STEPS = 50  # 0.5 s episodes: every check below is about the file, not the length


@pytest.fixture(scope="module")
def played():
    """Seeds 0-3 of the classical controller, 0.5 s each, played by the repo's harness."""
    from panda_lead import harness

    ctrl = harness.build("classical", STEPS)
    return list(rollout.iter_record(ctrl.config, ctrl.act, [0, 1, 2, 3], None, ctrl.meta))


def write_set(root: Path, prefix: str, rollouts) -> Path:
    for r in rollouts:
        rollout.save(r, rollout.rollout_path(prefix, r.seed, root))
    return root / prefix


def keys(r: rollout.Rollout) -> list[str]:
    """The arrays a rollout holds (the optional ones where present)."""
    return [k for k in (*rollout.ARRAY_KEYS, *rollout.OPTIONAL_KEYS) if getattr(r, k) is not None]


def copy(r: rollout.Rollout) -> rollout.Rollout:
    return dataclasses.replace(r, **{k: np.array(getattr(r, k)) for k in keys(r)},
                               meta=dict(r.meta))


# --- the rollout format checks its invariants on read (#7-#10) ------------------------------

def test_an_untouched_set_loads(played, tmp_path):
    write_set(tmp_path, "base", played)
    loaded = rollout.load_prefix("base", tmp_path)
    assert sorted(loaded) == [0, 1, 2, 3]
    assert np.array_equal(loaded[2].ee_pos, played[2].ee_pos)


def test_rows_beyond_the_meta_duration_are_refused(played, tmp_path):
    """#7: a file with twice the rows its meta's duration allows (the second half 20 cm off)
    used to be scored over all of them."""
    r = copy(played[1])
    for k in keys(r):
        a = getattr(r, k)
        setattr(r, k, np.concatenate([a, a]))
    r.t = 0.01 * np.arange(1, 2 * STEPS + 1)
    r.ee_pos[STEPS:] += [0.2, 0, 0]
    path = rollout.save(r, tmp_path / "seed_0001.npz")
    with pytest.raises(RolloutError, match=f"{2 * STEPS} rows, but its meta says 0.5 s at "
                                           f"0.01 s = {STEPS} steps"):
        rollout.load(path)


@pytest.mark.parametrize("value", [0.0, -0.3, 0.125])
def test_a_time_off_the_meta_step_is_refused(played, tmp_path, value):
    """#7: a zero or negative t made one seed's settled error NaN and dropped it from one set."""
    r = copy(played[0])
    r.t[10] = value
    path = rollout.save(r, tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError, match="t is .* s at step 10, but step 10 of its meta's"):
        rollout.load(path)


def test_an_episode_that_ended_early_still_loads(played, tmp_path):
    """Fewer rows than the duration is a failed episode: it loads, and metrics charges it."""
    r = copy(played[0])
    for k in keys(r):
        setattr(r, k, getattr(r, k)[:20])
    r.meta["failure"] = "unstable"
    r.t[-1] = 0.0  # MuJoCo resets an unstable simulation's clock: the last row is not checked
    assert len(rollout.load(rollout.save(r, tmp_path / "seed_0000.npz")).t) == 20


def test_another_seeds_episode_under_this_seed_is_refused(played, tmp_path):
    """#8: seed 3's episode relabelled seed 2 (same shape or not) was paired with seed 2."""
    r = copy(played[3])
    r.meta["seed"] = 2
    path = rollout.save(r, tmp_path / "seed_0002.npz")
    with pytest.raises(RolloutError, match="target_pos at step 0 is not seed 2's"):
        rollout.load(path)


@pytest.mark.parametrize("key", ["target_pos", "target_vel", "target_acc"])
def test_an_edited_target_is_refused(played, tmp_path, key):
    """#8: target_pos := ee_pos scored 0 error."""
    r = copy(played[1])
    if key == "target_pos":
        r.target_pos = r.ee_pos.copy()
    else:
        getattr(r, key)[30, 2] += 0.5
    path = rollout.save(r, tmp_path / "seed_0001.npz")
    with pytest.raises(RolloutError, match=f"{key} at step .* is not seed 1's"):
        rollout.load(path)


def test_two_files_claiming_one_seed_are_refused(played, tmp_path):
    """#9: seed_0011.npz holding seed 3 + 5 cm silently replaced seed 3 (or was dropped)."""
    folder = write_set(tmp_path, "dup", played)
    r = copy(played[3])
    r.ee_pos += [0.05, 0, 0]
    rollout.save(r, folder / "seed_0011.npz")
    with pytest.raises(RolloutError, match="seed_0011.npz: .*its meta says seed 3, so it "
                                           "should be named seed_0003.npz"):
        rollout.load_prefix("dup", tmp_path)
    from panda_lead.metrics import load_set

    with pytest.raises(UserError, match="seed_0011"):
        load_set("dup", tmp_path)


@pytest.mark.parametrize("key,dtype,words", [
    ("ee_pos", np.int64, "ee_pos has dtype int64, expected numbers"),
    ("t", np.int32, "t has dtype int32, expected numbers"),
    ("self_collision", np.int64, "self_collision has dtype int64, expected bool"),
    ("reachable", np.uint8, "reachable has dtype uint8, expected bool"),
])
def test_integer_arrays_are_refused(played, tmp_path, key, dtype, words):
    """#10: ee_pos as int64 (+5.72 cm on one seed), self_collision = 7 (700% of the time)."""
    r = copy(played[0])
    setattr(r, key, (getattr(r, key) * (7 if key == "self_collision" else 1)).astype(dtype))
    path = rollout.save(r, tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError, match=words):
        rollout.load(path)


def test_load_set_keeps_the_traceback_of_a_bug(monkeypatch, tmp_path, played):
    """Issue 38: load_set turned any ValueError into a user error, hiding real bugs."""
    from panda_lead.metrics import load_set

    write_set(tmp_path, "base", played)

    def broken(path):
        raise ValueError("a bug in the reader")

    monkeypatch.setattr(rollout, "load", broken)
    with pytest.raises(ValueError, match="a bug in the reader"):
        load_set("base", tmp_path)
    monkeypatch.undo()
    with pytest.raises(UserError, match="no rollouts under"):
        load_set("nothing", tmp_path)
