"""Facts stated once (issue 38's review): the failure labels, the largest seed and the
observation-size hint each have one home that every other module uses, so a change to one
cannot leave a stale copy behind."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "panda_lead"


def _sources():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield path.relative_to(PACKAGE).as_posix(), ast.parse(path.read_text())


def _picks_a_label(node) -> bool:
    """``"unstable" if ... else "self_collision"``: a conditional choosing between the labels."""
    return (isinstance(node, ast.IfExp)
            and {getattr(node.body, "value", None), getattr(node.orelse, "value", None)}
            == {"unstable", "self_collision"})


def test_the_failure_labels_are_written_only_in_config():
    writers = sorted(name for name, tree in _sources()
                     if any(_picks_a_label(n) for n in ast.walk(tree)))
    assert writers == ["config.py"], writers


def test_max_seed_is_assigned_once():
    homes = sorted(name for name, tree in _sources() for n in ast.walk(tree)
                   if isinstance(n, ast.Assign | ast.AnnAssign)
                   and any(isinstance(t, ast.Name) and t.id == "MAX_SEED"
                           for t in (n.targets if isinstance(n, ast.Assign) else [n.target])))
    assert homes == ["seeds.py"], homes


def test_the_labels_reach_every_path():
    """The single env's fast step, the reference step and the vector env name a blown-up
    episode alike (the label comes from one function)."""
    from panda_lead.config import failure_label, failure_of

    assert failure_label(True) == "unstable" and failure_label(False) == "self_collision"
    assert failure_of({"unstable": [False, True]}, 1, True) == failure_label(True)
    assert failure_of({"unstable": [True]}, 0, False) is None
