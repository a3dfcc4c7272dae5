"""Training: the config (`TrainConfig`) and presets, the training envs and their seeding, the
evaluation runs are selected on, the callbacks, the loop (`train`) and the archive.

The names below load with their submodule on first use (PEP 562): most of them pull in
stable-baselines3 and torch (~5 s), which `training.config` and `training.presets` do not need,
so train.py refuses a bad flag without waiting for them.
"""

from __future__ import annotations

import importlib

_WHERE = {
    "archive_model": "archive", "write_card": "archive",
    "SpeedCurriculum": "callbacks", "speed_cap": "callbacks",
    "REFERENCE_HPARAMS": "config", "TrainArgs": "config", "TrainConfig": "config",
    "make_vec_env": "envs",
    "evaluate": "evaluation",
    "TrainingInterrupted": "loop", "train": "loop",
    "PRESETS": "presets", "get_preset": "presets", "preset_table": "presets",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value  # found directly from now on
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
