"""Shared test helpers: the repo root, running one of its scripts as a user would, and the
one-line refusal every command line gives bad input."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# MuJoCo picks its GL platform once, when it is first imported; importing panda_lead chooses
# EGL on a headless machine. Import it before any test module imports mujoco itself, so a
# render test works whichever test files run before it (test_core imports mujoco first).
import panda_lead  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]


def run_script(script, *args, cwd=None, env=None, check=False, **kwargs) -> subprocess.CompletedProcess:
    """Run a repo script (path relative to the root) with this interpreter; text output."""
    full_env = {**os.environ, **(env or {})}
    cmd = [sys.executable, str(ROOT / script), *map(str, args)]
    return subprocess.run(cmd, cwd=cwd or ROOT, env=full_env, capture_output=True, text=True,
                          check=check, **kwargs)


def one_line(out: subprocess.CompletedProcess, *words: str) -> str:
    """Exit status 2 and a single `error:` line holding every word; returns the line."""
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), out.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]
