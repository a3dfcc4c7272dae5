"""Shared test helpers: the repo root, running one of its scripts as a user would, and the
one-line refusal every command line gives bad input."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# torch's MKL picks its matrix kernels by CPU (AVX-512, AVX2 or SSE, by model and vendor), and
# float32 sums come out in another order. A lead policy's closed loop damps that below a card's
# six digits; an IK-free policy's is chaotic and moves by millimetres (archive/ikfree's seed 0:
# 5.408674 cm on the SSE4.2 path its card was written on, 5.092068 with AVX-512, 5.785697 with
# AVX2). The tests pin that path, read by MKL when torch first calls it, so that they pass on
# any x86 CPU (docs/results.md, Reproducibility).
os.environ.setdefault("MKL_ENABLE_INSTRUCTIONS", "SSE4_2")

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
