"""sweep.py: the embedded default, and many workers sharing one PostgreSQL study with a kill."""

import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = "--n-envs 2 --vec-env dummy --n-steps 64 --batch-size 64 --n-epochs 1 --eval-steps 50"


def sweep_cmd(*args):
    return [sys.executable, str(ROOT / "studies" / "sweep.py"), *map(str, args)]


def test_embedded_grid_runs_each_point_once_with_two_workers(tmp_path):
    out = subprocess.run(
        sweep_cmd("--name", "g", "--presets", "v1", "v5", "--seeds", "1", "2", "--timesteps",
                  "256", "--eval-freq", "128", "--workers", "2", f"--train-args={TINY}"),
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert (tmp_path / "sweeps" / "g.db").is_file()  # SQLite file, no server
    import optuna

    study = optuna.load_study(study_name="g", storage=f"sqlite:///{tmp_path}/sweeps/g.db")
    done = Counter((t.params["preset"], t.params["seed"]) for t in study.trials
                   if t.state.name == "COMPLETE")
    assert done == {("v1", 1): 1, ("v1", 2): 1, ("v5", 1): 1, ("v5", 2): 1}
    assert "per configuration" in out.stdout and "preset=v5" in out.stdout
    rep = subprocess.run(sweep_cmd("--report", "g"), cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert rep.returncode == 0 and "95% interval" in rep.stdout
    arch = subprocess.run(sweep_cmd("--archive", "g", "--archive-as", "gbest"), cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert arch.returncode == 0, arch.stderr[-2000:]
    assert (tmp_path / "archive" / "gbest.zip").is_file()
    assert (tmp_path / "archive" / "gbest.json").is_file()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def postgres():
    """A throwaway PostgreSQL server on loopback (Debian's postgresql package; .ci/run installs
    it). Missing binaries fail the test: it must never be skipped silently."""
    bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not bins:
        pytest.fail("PostgreSQL server binaries not found: apt-get install postgresql")
    bindir = Path(bins[-1]).parent
    as_root = os.geteuid() == 0
    prefix = ["runuser", "-u", "postgres", "--"] if as_root else []  # initdb refuses root
    base = Path(tempfile.mkdtemp(prefix="pgtest"))
    if as_root:
        pg = pwd.getpwnam("postgres")
        os.chown(base, pg.pw_uid, pg.pw_gid)
    port = _free_port()
    data = base / "data"

    def pg(*cmd):
        subprocess.run([*prefix, *map(str, cmd)], check=True, capture_output=True, timeout=120)

    pg(bindir / "initdb", "-D", data, "-U", "postgres", "--auth=trust")
    pg(bindir / "pg_ctl", "-D", data, "-l", base / "log", "-w", "-o",
       f"-p {port} -k {base} -c listen_addresses=127.0.0.1", "start")
    try:
        pg(bindir / "createdb", "-h", "127.0.0.1", "-p", port, "-U", "postgres", "sweeps")
        yield f"postgresql+psycopg2://postgres@127.0.0.1:{port}/sweeps"
    finally:
        subprocess.run([*prefix, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate",
                        "stop"], capture_output=True, timeout=60)
        shutil.rmtree(base, ignore_errors=True)


def test_workers_share_a_postgres_study_and_survive_a_kill(postgres, tmp_path):
    import optuna

    common = ["--name", "pg", "--presets", "v1", "v5", "--seeds", "1", "2", "--timesteps",
              "3072", "--eval-freq", "512", "--heartbeat", "1", "--storage", postgres,
              f"--train-args={TINY}"]
    # Worker A starts alone and is killed (SIGKILL: no chance to clean up) mid-trial.
    a = subprocess.Popen(sweep_cmd(*common), cwd=tmp_path, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    running = []
    while time.time() < deadline and not running:
        time.sleep(0.2)
        try:
            study = optuna.load_study(study_name="pg", storage=postgres)
            running = [t for t in study.get_trials(deepcopy=False) if t.state.name == "RUNNING"]
        except KeyError:
            continue
    assert running, "worker A never started a trial"
    time.sleep(0.5)
    a.send_signal(signal.SIGKILL)
    a.wait(timeout=30)
    # Two more workers (as if on two machines) share the study and finish it.
    b, c = (subprocess.Popen(sweep_cmd(*common), cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for _ in range(2))
    for p in (b, c):
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-3000:]

    trials = optuna.load_study(study_name="pg", storage=postgres).get_trials(deepcopy=False)
    states = Counter(t.state.name for t in trials)
    done = Counter((t.params["preset"], t.params["seed"]) for t in trials
                   if t.state.name == "COMPLETE")
    assert done == {("v1", 1): 1, ("v1", 2): 1, ("v5", 1): 1, ("v5", 2): 1}, [
        (t.number, t.state.name, t.params, dict(t.system_attrs)) for t in trials]
    assert states["FAIL"] == 1 and states["RUNNING"] == 0  # the killed trial, marked failed
    failed = next(t for t in trials if t.state.name == "FAIL")
    retried = [t for t in trials if t.system_attrs.get("failed_trial") == failed.number]
    assert len(retried) == 1 and retried[0].state.name == "COMPLETE"
