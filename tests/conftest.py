"""Shared test helpers: the repo root, running one of its scripts as a user would (in a
subprocess, or its main function in-process), the one-line refusal every command line gives
bad input, and one tiny trained run shared by the tests that need a run folder or a model."""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

# MuJoCo picks its GL platform once, when it is first imported; importing panda_lead chooses
# EGL on a headless machine. Import it before any test module imports mujoco itself, so a
# render test works whichever test files run before it (test_core imports mujoco first).
import panda_lead  # noqa: F401

# Loading triton (torch._dynamo imports it, at the first optimiser SB3 builds) after an EGL
# render has loaded Mesa's LLVM segfaults the process (reproduced: render, then
# `import torch._dynamo`, exit 139; the other order works). The tests render and train in one
# process, in any order: load it first.
try:
    import torch._dynamo  # noqa: F401
except ImportError:  # torch without dynamo: nothing to order
    pass

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


def run_in_process(script, *args, cwd=None, **_ignored) -> subprocess.CompletedProcess:
    """`run_script`'s result without the process: the script (a path, or relative to the root)
    run as ``python script args`` would run it (``__main__``, sys.argv, the working folder),
    its output captured, its SystemExit turned into the exit status. A bug raises here, as a
    traceback. No `import torch` per call: keep subprocesses for what is the process's own
    (signals, the real exit status of one case per script)."""
    import contextlib
    import io
    import runpy

    path = Path(script) if Path(script).is_absolute() else ROOT / script
    argv = [str(path), *map(str, args)]
    out, err = io.StringIO(), io.StringIO()
    code = 0
    old_argv, old_cwd = sys.argv, os.getcwd()
    try:
        sys.argv = argv
        os.chdir(cwd or ROOT)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                runpy.run_path(str(path), run_name="__main__")
            except SystemExit as exc:
                c = exc.code
                code = 0 if c is None else c if isinstance(c, int) else 1
                if not isinstance(c, int | None):
                    print(c, file=sys.stderr)
    finally:
        sys.argv = old_argv
        os.chdir(old_cwd)
    return subprocess.CompletedProcess(argv, code, out.getvalue(), err.getvalue())


def main_exit(main, argv, capsys) -> tuple[int, str, str]:
    """Call a script's main function in-process as its command line would: the exit status
    (0 when it returns), stdout and stderr. Cheaper than a subprocess (no `import torch`);
    keep subprocesses for what is the process's own (signals, the real exit of one case)."""
    capsys.readouterr()  # only what this call prints
    with _exits() as status:
        main(list(map(str, argv)))
    out, err = capsys.readouterr()
    return status.code, out, err


class _exits:
    """Catch SystemExit; ``code`` is its status as the shell sees it (0 for a plain return)."""

    code = 0

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is SystemExit:
            c = value.code
            self.code = 0 if c is None else c if isinstance(c, int) else 1
            return True
        return False


def one_line_in_process(main, argv, capsys, *words: str) -> str:
    """`one_line` for an in-process call: exit status 2 and a single `error:` line."""
    code, out, err = main_exit(main, argv, capsys)
    return one_line(subprocess.CompletedProcess(argv, code, out, err), *words)


# --- one tiny trained run, shared ----------------------------------------------------------

TINY_TRAIN = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
              "--eval-steps", "20", "--checkpoint-freq", "128", "--no-progress"]


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """One tiny training run for every test that needs a run folder or an archived model
    (test_cli, test_training; each trained its own): train.py as a user runs it, 200 steps
    asked (whole rollouts of 64 x 2 end it at 256), SubprocVecEnv, evaluations and
    checkpoints every 128 steps; then resumed to 512 steps and archived as archive/tiny.
    Read-only: a test that writes into it takes `tiny_run_copy`. Trained once per test
    session, also under pytest-xdist: the first worker to ask trains it in the workers'
    shared temporary folder under a file lock, the others wait for it and read it (pytest-
    xdist's documented recipe; each worker trained its own, ~80 s of setup each).

    Returns (work folder holding runs/ and archive/, the run folder, the first run's and the
    resume's CompletedProcess)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):  # no xdist workers: this process's own
        return _train_tiny(tmp_path_factory.mktemp("tiny_run"))
    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp().parent  # the same folder for every worker
    record = shared / "tiny_run.json"
    with FileLock(str(shared / "tiny_run.lock")):
        if not record.is_file():
            tmp, _, first, resumed = _train_tiny(shared / "tiny_run")
            record.write_text(json.dumps({"tmp": str(tmp), "runs": [
                [p.args if isinstance(p.args, str) else [str(a) for a in p.args],
                 p.returncode, p.stdout, p.stderr] for p in (first, resumed)]}))
    saved = json.loads(record.read_text())
    tmp = Path(saved["tmp"])
    first, resumed = (subprocess.CompletedProcess(*r) for r in saved["runs"])
    (run_dir,) = (tmp / "runs").iterdir()
    return tmp, run_dir, first, resumed


def _train_tiny(tmp: Path):
    tmp.mkdir(parents=True, exist_ok=True)
    first = run_script("train.py", "--timesteps", "200", "--vec-env", "subproc",
                       "--eval-freq", "128", "--runs-dir", tmp / "runs", *TINY_TRAIN, cwd=tmp,
                       env={"MUJOCO_GL": "egl"}, timeout=600)
    assert first.returncode == 0, first.stderr
    (run_dir,) = (tmp / "runs").iterdir()
    resumed = run_script("train.py", "--resume", run_dir, "--timesteps", "512",
                         "--archive", "tiny", "--no-progress", cwd=tmp,
                         env={"MUJOCO_GL": "egl"}, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    return tmp, run_dir, first, resumed


@pytest.fixture
def tiny_run_copy(tiny_run, tmp_path):
    """The shared tiny run's work folder copied for a test that writes into it."""
    import shutil

    tmp, run_dir, first, resumed = tiny_run
    copy = tmp_path / "work"
    shutil.copytree(tmp, copy)
    return copy, copy / "runs" / run_dir.name, first, resumed


class PipeLines:
    """Every line of a child's pipe, read by a thread as it comes (so the pipe never fills
    and a silent child cannot block the test)."""

    def __init__(self, pipe):
        self.lines: list[str] = []
        self._new = queue.Queue()
        self._thread = threading.Thread(target=self._read, args=(pipe,), daemon=True)
        self._thread.start()

    def _read(self, pipe):
        for line in pipe:
            self.lines.append(line)
            self._new.put(line)

    def wait_for(self, text: str, hang_guard: float = 600) -> None:
        """Until a line contains ``text`` (the event; the guard only catches a hang)."""
        deadline = time.monotonic() + hang_guard
        while (left := deadline - time.monotonic()) > 0:
            try:
                if text in self._new.get(timeout=left):
                    return
            except queue.Empty:
                break
        raise AssertionError(f"never saw {text!r}: {''.join(self.lines)}")

    def text(self) -> str:
        """Everything, once the child has exited."""
        self._thread.join(timeout=60)
        return "".join(self.lines)
