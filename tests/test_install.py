"""The project as a third party gets it: installed (not editable) into a fresh virtual
environment from the lock file, offline from uv's cache, then used from a folder outside the
repository with no PYTHONPATH: the env by id, a model card's snippet, 2,048 steps of SB3, and
the ``panda-lead`` console command (its help, a rollout set, adopting the SB3 model)."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_group(cmd, timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True, timeout=...)``, but the child leads
    a process group of its own, killed whole whatever happens (a timeout, a failure, Ctrl-C, or
    a normal end that left something behind): uv's children and theirs go too, where
    subprocess.run would kill uv alone and leave them running."""
    proc = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, **kwargs)
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        if proc.returncode is None:  # interrupted: reap the child and close its pipes
            proc.communicate()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The python of a fresh venv holding the project as a wheel would install it."""
    uv = shutil.which("uv")
    assert uv, "uv is needed to install the project (pip install uv)"
    tmp = tmp_path_factory.mktemp("install")
    copy = tmp / "project"  # the working tree's files as git sees them, nothing else
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                           capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, files):
        src = ROOT / name
        if src.is_file():
            (copy / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, copy / name)
    venv = tmp / "venv"
    env = {**os.environ, "UV_PROJECT_ENVIRONMENT": str(venv)}
    env.pop("VIRTUAL_ENV", None)
    try:
        out = run_group([uv, "sync", "--frozen", "--offline", "--no-dev", "--no-editable"],
                        timeout=1800, cwd=copy, env=env)
        assert out.returncode == 0, out.stderr[-3000:]
        shutil.rmtree(copy)  # nothing of the source tree is left to import from
        yield venv / "bin" / "python"
    finally:
        # pytest keeps the last three runs' tmp folders: a venv is GBs where uv cannot
        # hard-link from its cache (another file system), so it goes when the module ends.
        shutil.rmtree(tmp, ignore_errors=True)


def run_outside(python: Path, code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return run_group([python, "-c", code], timeout=900, cwd=tmp_path, env=env)


def _dead(pid: int) -> bool:
    """Whether ``pid`` has ended (gone, or a zombie nobody has reaped yet); waits up to a
    minute for a kill to land."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1][0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state in "ZX":
            return True
        time.sleep(0.05)
    return False


def test_run_group_kills_the_grandchildren_on_a_timeout_and_after_a_normal_end(tmp_path):
    pid_file = tmp_path / "pid"
    # A child that starts a grandchild and waits for it: the timeout ends both.
    with pytest.raises(subprocess.TimeoutExpired):
        run_group(["sh", "-c", f"sleep 120 >/dev/null 2>&1 & echo $! > {pid_file}; wait"],
                  timeout=5)
    assert _dead(int(pid_file.read_text()))
    # A child that ends at once and leaves its grandchild behind: that goes too.
    out = run_group(["sh", "-c", "sleep 120 >/dev/null 2>&1 & echo $!"], timeout=60)
    assert out.returncode == 0 and _dead(int(out.stdout))


def test_the_installed_package_is_not_the_checkout(installed, tmp_path):
    out = run_outside(installed, "import panda_lead; print(panda_lead.__file__)", tmp_path)
    assert out.returncode == 0, out.stderr
    assert "site-packages" in out.stdout and str(ROOT) not in out.stdout


def test_the_env_is_made_by_id_from_any_folder(installed, tmp_path):
    code = """
import gymnasium as gym
e = gym.make("panda_lead:PandaLead-v0")          # imports the package itself
obs, info = e.reset(seed=0)
obs, r, term, trunc, info = e.step(e.action_space.sample())
import panda_lead                                # registers both ids
for env_id in ("PandaLead-v0", "panda_lead/PandaLead-v0"):
    gym.make(env_id).reset(seed=0)
print("ok", obs.shape, info["distance"] > 0)
"""
    out = run_outside(installed, code, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok (15,) True"


def test_a_model_cards_snippet_runs_from_any_folder(installed, tmp_path):
    card = (ROOT / "archive" / "v5_5m.md").read_text()
    snippet = re.search(r"```python\n(.*?)```", card, re.S).group(1)
    promised = re.search(r"# card: ([0-9.]+) cm", snippet).group(1)
    out = run_outside(installed, snippet, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == f"test seed 0: mean error {promised} cm"


@pytest.mark.slow  # 2,048 steps of stock SB3 in the fresh venv; adopting is in the default
# tier in-process (test_adopt, test_zoo), the installed command's --help there lists --adopt
def test_sb3_trains_on_the_installed_env_and_the_installed_command_adopts_it(installed,
                                                                             tmp_path):
    code = """
import gymnasium as gym, torch
from stable_baselines3 import PPO
import panda_lead
torch.set_num_threads(1)  # stock SB3 on 2 cores is several times slower without it
model = PPO("MlpPolicy", gym.make("PandaLead-v0"), n_steps=1024, batch_size=256, n_epochs=1,
            device="cpu", seed=0)
model.learn(2048)
model.save("mine.zip")
print("steps", model.num_timesteps)
"""
    out = run_outside(installed, code, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "steps 2048"
    # eval --adopt from the installed package (issue 40: it needed the checkout's eval.py)
    out = run_command(installed, ["eval", "--adopt", "mine.zip", "--name", "mine"], tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    written = {p.name for p in (tmp_path / "archive").iterdir()}
    assert {"mine.zip", "mine.json", "mine.md"} <= written, written
    again = run_command(installed, ["eval", "--adopt", "mine.zip", "--name", "mine"], tmp_path)
    assert again.returncode == 2 and "choose another --name name" in again.stderr


def run_command(python: Path, argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """The installed ``panda-lead`` console command (beside the venv's python), run in ``cwd``
    with nothing of the checkout on the path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return run_group([python.parent / "panda-lead", *argv], timeout=900, cwd=cwd, env=env)


def test_the_installed_console_command_runs_outside_the_checkout(installed, tmp_path):
    out = run_command(installed, ["--help"], tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    for name in ("train", "eval", "ikpd", "metrics", "env", "trajectory"):
        assert f"  {name} " in out.stdout, out.stdout
    helps = {name: run_command(installed, [name, "--help"], tmp_path)
             for name in ("eval", "train", "metrics")}
    for name, out in helps.items():
        assert out.returncode == 0, (name, out.stderr[-2000:])
        assert out.stdout.startswith(f"usage: panda-lead {name} "), out.stdout[:200]
    assert "--adopt PATH.zip --name NAME" in helps["eval"].stdout
    out = run_command(installed, ["ikpd", "--seeds", "0-1", "--prefix", "c", "--duration",
                                  "0.2"], tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "rollouts" / "c").glob("seed_*.npz")) == [
        "seed_0000.npz", "seed_0001.npz"]
    out = run_command(installed, ["evl"], tmp_path)
    assert out.returncode == 2 and out.stderr.startswith("error: unknown command 'evl'")


def test_the_declared_mujoco_floor_has_the_batch_api_the_core_needs():
    """Regression (issue 21): pyproject said mujoco>=3.2 while the core needs mujoco.batch,
    which arrived in 4.0; a resolver could pick a MuJoCo the core cannot run on."""
    import importlib
    import tomllib

    import mujoco
    from packaging.requirements import Requirement
    from packaging.version import Version

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    spec = next(Requirement(d).specifier for d in deps if Requirement(d).name == "mujoco")
    floor = min(Version(s.version) for s in spec if s.operator in (">=", "=="))
    assert floor >= Version("4.0"), spec
    assert hasattr(importlib.import_module("mujoco.batch"), "Batch")
    assert Version(mujoco.__version__) >= floor
