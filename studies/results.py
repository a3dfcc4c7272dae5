"""Every table and figure under results/ from the runs of studies/queue.sh, and the index
results/README.md.

    uv run studies/results.py tables      # from a fresh clone: what reads committed files only
    uv run studies/results.py             # everything (an hour or more on 2 cores)
    uv run studies/results.py --dry-run   # what is stale, and the command that remakes it
    uv run studies/results.py index       # rewrite results/README.md alone

A step is rebuilt when it is stale: an output is missing, or what it reads (its inputs, its
command) is not what its outputs were made from. Each output's stamp in results/manifest.json
records the command, the commit and a digest of the inputs: the contents of committed inputs
(run summaries, archived models, so a new model hash is a new digest) and the names, sizes
and modification times of uncommitted ones (rollout sets, sweep folders; a newer set is a new
digest). `--force` rebuilds every selected step, `--only GLOB` selects outputs by path.

A step runs into a scratch folder and its outputs replace the committed ones only when it
succeeds: a failing step leaves the committed table as it was (and the run exits 1, naming it).
A markdown table's first line says the command and commit that made it. Before the tables, the
`all` section refreshes what they read (what studies/results.sh did first): each sweep's summaries, the
archived models it chooses (only when missing) and the rollout sets, rebuilt when missing or
played by a model other than the archived one (or setting, for the online corrections'); with
`--only`, just the registered rollout sets the selected steps read, and no sweep.
"""

from __future__ import annotations

import fnmatch
import glob
import hashlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results_index import write_index  # noqa: E402
from results_steps import Step, table_steps  # noqa: E402

from panda_lead.atomicio import atomic_write  # noqa: E402
from panda_lead.errors import UserError, exit_on_user_error, parse_cli  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = "results/manifest.json"
UNCOMMITTED = ("rollouts/", "sweeps/", "runs/")  # big generated folders: digest by stat


@dataclass
class Args:
    section: tyro.conf.Positional[Literal["all", "tables", "index"]] = "all"
    """all: every step (needs the runs' sweeps and rollout sets); tables: the steps that read
    committed files only; index: rewrite results/README.md alone."""
    only: list[str] = field(default_factory=list)
    """Only the steps with an output matching one of these globs (e.g. 'results/studies/v5/*')."""
    force: bool = False
    """Rebuild the selected steps even when they are current."""
    dry_run: bool = False
    """Print each stale step's command and why it is stale; run nothing, write nothing."""


def commit(root: Path) -> str:
    """HEAD's short hash, '+dirty' when tracked code differs from it."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=root, text=True,
                              capture_output=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                                "panda_lead", "studies", "*.py"], cwd=root, text=True,
                               capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def digest(root: Path, paths: tuple[str, ...]) -> str | None:
    """One hash over what the inputs hold; None when one is missing."""
    h = hashlib.sha256()
    for rel in paths:
        p = root / rel
        if not p.exists():
            return None
        # dot-files are machine-local (the .NAME.lock beside a summary, which git ignores): in
        # the hash they made a fresh clone see its committed tables as stale
        files = (sorted(f for f in p.rglob("*") if f.is_file() and not f.name.startswith("."))
                 if p.is_dir() else [p])
        for f in files:
            name = f.relative_to(root).as_posix()
            h.update(name.encode() + b"\0")
            if rel.startswith(UNCOMMITTED):
                st = f.stat()
                h.update(f"{st.st_size}:{st.st_mtime_ns}".encode())
            else:
                h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()[:16]


def shown(step: Step) -> str:
    """The step's command as a reader runs it."""
    words = [w.replace("{dir}", str(Path(step.outs[0]).parent)) for w in step.argv]
    for i, out in enumerate(step.outs):
        words = [w.replace(f"{{out{i}}}", out) for w in words]
    cmd = "uv run " + shlex.join(words)
    return cmd + (f" > {step.outs[0]}" if step.stdout else "")


def load_manifest(root: Path) -> dict:
    p = root / MANIFEST
    if not p.exists():
        return {}
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"{MANIFEST} is not JSON ({exc}); restore it from git") from None


def staleness(root: Path, step: Step, manifest: dict) -> str | None:
    """Why the step must run (None: current). 'missing input' when it cannot run here."""
    inputs = digest(root, step.inputs)
    if inputs is None:
        missing = [p for p in step.inputs if not (root / p).exists()]
        return f"missing input: {', '.join(missing)}"
    for out in step.outs:
        stamp = manifest.get(out)
        if not (root / out).exists():
            return f"{out} is missing"
        if stamp is None:
            return f"{out} has no stamp"
        if stamp.get("command") != shown(step):
            return f"{out} was made by another command"
        if stamp.get("inputs") != inputs:
            return f"{out}'s inputs changed"
    return None


def _expand(root: Path, word: str) -> list[str]:
    if "*" not in word:
        return [word]
    hits = sorted(glob.glob(word, root_dir=root))
    if not hits:
        raise FileNotFoundError(f"nothing matches {word}")
    return hits


def run_step(root: Path, step: Step, manifest: dict, made_by: str) -> bool:
    """Run the step into a scratch folder; move its outputs into place if it succeeds."""
    (root / "results").mkdir(exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=".step-", dir=root / "results"))
    try:
        tmp = [scratch / Path(o).name for o in step.outs]
        argv: list[str] = []
        for w in step.argv:
            w = w.replace("{dir}", str(scratch))
            for i, t in enumerate(tmp):
                w = w.replace(f"{{out{i}}}", str(t))
            argv += _expand(root, w)
        cmd = [sys.executable, *argv] if argv[0].endswith(".py") else argv
        env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
        with open(tmp[0] if step.stdout else os.devnull, "w") as out:
            rc = subprocess.run(cmd, cwd=root, stdout=out, env=env).returncode
        absent = [str(t) for t in tmp if not t.exists()]
        if rc != 0 or absent:
            why = f"exit status {rc}" if rc else f"did not write {', '.join(absent)}"
            print(f"FAILED ({why}): {shown(step)}; the committed outputs are unchanged",
                  file=sys.stderr)
            return False
        inputs = digest(root, step.inputs)
        for out, t in zip(step.outs, tmp, strict=True):
            if t.suffix in (".md", ".txt"):
                text = t.read_text().replace(str(scratch), str(Path(out).parent))
                if step.per_seed_dropped:
                    text = _drop_per_seed(text)
                if t.suffix == ".md":
                    text = f"Made by `{shown(step)}` at commit {made_by}.\n\n" + text
                t.write_text(text)
            (root / out).parent.mkdir(parents=True, exist_ok=True)
            os.replace(t, root / out)
            manifest[out] = {"command": shown(step), "commit": made_by, "inputs": inputs}
        return True
    except FileNotFoundError as exc:
        print(f"FAILED ({exc}): {shown(step)}; the committed outputs are unchanged",
              file=sys.stderr)
        return False
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _drop_per_seed(text: str) -> str:
    """metrics.py --breakdown's 'per seed' section (a line per seed) up to its blank line."""
    kept, skip = [], False
    for line in text.splitlines(keepends=True):
        if line.startswith("per seed"):
            skip = True
        if skip and not line.strip():
            skip = False
            continue
        if not skip:
            kept.append(line)
    return "".join(kept)


def save_manifest(root: Path, manifest: dict) -> None:
    with atomic_write(root / MANIFEST, ".json") as tmp:
        Path(tmp).write_text(json.dumps(dict(sorted(manifest.items())), indent=1) + "\n")


def save_stamps(root: Path, stamps: dict) -> None:
    """Merge these outputs' stamps into the manifest as it is on disk now, under a lock: two
    runs side by side (each --only its own steps) each keep the other's stamps. (Writing the
    whole manifest read at the start once dropped a stamp the other run had added.)"""
    from filelock import FileLock

    with FileLock(str(root / "results" / ".manifest.lock")):
        on_disk = load_manifest(root)
        on_disk.update(stamps)
        save_manifest(root, on_disk)


def select(steps: list[Step], section: str, only: list[str]) -> list[Step]:
    keep = [s for s in steps if section == "all" or s.section == "tables"]
    if only:
        keep = [s for s in keep if any(fnmatch.fnmatch(o, g) for o in s.outs for g in only)]
        if not keep:
            raise UserError(f"--only {' '.join(only)} matches no output of the {section} steps")
    return keep


def build(root: Path, steps: list[Step], force: bool = False, dry_run: bool = False) -> int:
    """Run the stale steps; 0 when every runnable one is current or succeeded, else 1."""
    manifest = load_manifest(root)
    made_by = commit(root)
    failed, cannot = [], []
    for step in steps:
        why = staleness(root, step, manifest)
        if why and why.startswith("missing input"):
            cannot.append(f"{shown(step)} ({why})")
            continue
        if why is None and not force:
            continue
        print(f"{'stale' if dry_run else 'run'}: {shown(step)} ({why or '--force'})", flush=True)
        if not dry_run:
            if run_step(root, step, manifest, made_by):
                save_stamps(root, {out: manifest[out] for out in step.outs})
            else:
                failed.append(shown(step))
    for c in cannot:
        print(f"kept as committed, cannot rebuild here: {c}")
    if failed:
        print(f"{len(failed)} step(s) failed, their committed outputs kept:", *failed,
              sep="\n  ", file=sys.stderr)
    return 1 if failed else 0


def _rollout_sets(steps: list[Step]) -> set[str]:
    """The rollout-set prefixes the steps read (their inputs under rollouts/)."""
    return {i.removeprefix("rollouts/") for step in steps for i in step.inputs
            if i.startswith("rollouts/")}


@exit_on_user_error
def main(argv: list[str] | None = None) -> int:
    args = parse_cli(Args, argv, description=__doc__, prog="studies/results.py")
    # a kill ends the run through its finally blocks: the scratch folder goes, tables stay
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    rc = 0
    if args.section != "index":
        steps = select(table_steps(), args.section, args.only)
        if args.section == "all" and not args.dry_run:
            from results_prepare import prepare

            # --only: just the rollout sets the selected steps read, no sweep
            prepare(ROOT, _rollout_sets(steps) if args.only else None)
        rc = build(ROOT, steps, args.force, args.dry_run)
    if not args.dry_run:
        write_index(ROOT, load_manifest(ROOT))
        print("wrote results/README.md")
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
