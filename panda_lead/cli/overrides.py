"""Env settings as typed, optional command-line flags (``--env.max-lead 0.1``,
``--env.ik.damping 0.1``): only the ones given apply, over a model's sidecar config or the
env's defaults. Shared by eval.py/ikpd.py and the model commands (--adopt)."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import field
from typing import Annotated

import tyro

from ..config import EnvConfig, config_docs


def _overrides_class(cls=EnvConfig, name: str = "EnvOverrides"):
    """``cls`` with every field optional (None: not given): what --env.X sets. A nested config
    (ik) becomes a nested overrides class, so --env.ik.damping sets that knob alone."""
    hints = typing.get_type_hints(cls)
    docs = config_docs(cls)
    fields = []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            sub = _overrides_class(kind, f"{kind.__name__}Overrides")
            fields.append((f.name, sub, field(default_factory=sub)))
            continue
        fields.append((f.name, Annotated[kind | None, tyro.conf.arg(
            help=docs[f.name], help_behavior_hint="(default: the model's, else the env's)")],
            field(default=None)))
    return dataclasses.make_dataclass(name, fields, frozen=True)


def given(overrides) -> dict:
    """The flags given, as EnvConfig.merged takes them ({"ik": {"damping": 0.1}, ...})."""
    out = {}
    for f in dataclasses.fields(overrides):
        v = getattr(overrides, f.name)
        if dataclasses.is_dataclass(v):
            v = given(v) or None
        if v is not None:
            out[f.name] = v
    return out


EnvOverrides = _overrides_class()
