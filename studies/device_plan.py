"""Issue 41's plan for a lent 16-core + GPU machine, as one script with a time bound per step.

    python3 studies/device_plan.py --wheels .whl --out "$OUT"     # on the device machine
    uv run studies/device_plan.py --small --out /tmp/plan           # dry run here (minutes)

The device machine is lent for about 15 minutes at a stretch, its start included, and has no
package registry: the wheels it lacks travel in .whl/ (docs/performance.md, "16 cores and a
GPU", says how they are fetched) and this script installs them into /tmp/site first. Then, each
step in its own process with its own time limit, most important first:

1. the machine: CPU, cores, GPU, torch, CUDA, mujoco;
2. `--device cuda` end to end: train (the gpu profile that `--device cuda` picks), resume,
   archive; the archived model comes back to be evaluated on a CPU machine (a test);
3. the env: `studies/bench.py --env-only` (physics, batched env per thread and on all threads,
   the physics-bound limit);
4. PPO samples/s through `train.py` itself (FastPPO, evaluations off; SB3's own time/fps, which
   starts after the process and env are built) for the reference configuration, the 2-core
   default with the CPU and the CUDA learner, and larger collections and minibatches; the peak
   memory (PSS) of each run's whole process tree;
5. quality: the gpu profile for 5M steps on two training seeds at once, each pinned to half
   the cores (samples, not seconds, decide quality; their wall time is not a throughput
   figure), evaluated every 250k steps, against the 2-core default's five seeds on the same
   evaluation grid.

Everything lands in --out: table.md (one table), log.txt (every step's output), bench_env.md,
and artifacts.tar.gz (the archived CUDA model, the quality runs' progress.csv, config.json and
best models). A step that runs out of time is killed and reported as such; the rest go on.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SITE = Path("/tmp/site")


@dataclasses.dataclass
class Args:
    out: Path = Path("device_plan_out")
    """Where table.md, log.txt, bench_env.md and artifacts.tar.gz go."""
    wheels: Path | None = None
    """A folder of wheels to install into /tmp/site first (the device machine's missing
    packages); none here, where uv has installed everything."""
    small: bool = False
    """Tiny budgets and the CPU instead of CUDA where there is none: a dry run of the script."""
    quality_steps: int = 5_000_000
    """Training steps of each quality run."""
    quality_limit_s: int = 170
    """Time limit of the quality runs (both run at once); a run cut short reports its curve."""
    quality_only: bool = False
    """Only step 5 (a second call on the machine, for another candidate's quality)."""
    curves: bool = False
    """Here, after the device: the quality runs' evaluation curves (their progress.csv, kept in
    results/bench/device_2026-11-26/) against the 2-core default's five seeds on the same
    250k-step grid: best error by 3M and 5M steps, steps to 2.5 cm; markdown to stdout."""
    test_quality: bool = False
    """Here, after the device: play the gpu profile's quality models (archive/seeds/
    gpu_profile_5m_s1/s2.zip, brought back from the machine) on the 1,000 test seeds and pair
    each with the 2-core default's same training seed (results/runs/curriculum_5m); markdown
    to stdout."""
    quality_flags: str = ""
    """Flags added to the quality runs' (after --profile gpu), e.g. "--n-envs 256 --batch-size
    8192"."""
    quality_seeds: list[int] = dataclasses.field(default_factory=lambda: [1, 2])
    """Training seeds of the quality runs, all at once, the cores split evenly between them."""
    quality_variants: str = ""
    """Instead of one run per seed, one run per ';'-separated entry, each entry train.py flags
    of its own (e.g. "--preset deploy_caps_armfilter --seed 3; --preset v5_err_decay --seed
    3"), all at once like the seeds."""
    quality_eval_freq: int = 250_000
    """Steps between the quality runs' evaluations (a study's own runs evaluate every 50,000
    steps, train.py's default: give that to runs that join one, so that its best model is
    chosen on the same grid)."""
    cprofile: int = 0
    """With --quality-only, first a cProfile of this many PPO iterations of the gpu profile
    (`studies/profile_update.py --variants fast --train-profile gpu --cprofile N`), its output
    in cprofile_gpu.txt."""


def wheels_given(argv: list[str]) -> Path | None:
    """--wheels, read before tyro exists: on the device tyro is one of the wheels."""
    for i, a in enumerate(argv):
        if a == "--wheels" and i + 1 < len(argv):
            return Path(argv[i + 1])
        if a.startswith("--wheels="):
            return Path(a.split("=", 1)[1])
    return None


class Log:
    """Every step's output, appended to log.txt and echoed (the device returns the tail)."""

    def __init__(self, path: Path):
        self.file = open(path, "a", buffering=1)

    def __call__(self, text: str) -> None:
        print(text, flush=True)
        self.file.write(text + "\n")


def install_wheels(wheels: Path) -> None:
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-compile",
           "--no-cache-dir", "--upgrade", "--target", str(SITE), *map(str, sorted(wheels.glob("*.whl")))]
    subprocess.run(cmd, check=True)
    # gymnasium-robotics is here only for its Franka meshes (core._mesh_assets): the trimmed
    # copy in .whl/ holds just them, which keeps the working tree under the device's 64 MiB.
    trimmed = wheels / "gymnasium_robotics"
    if trimmed.is_dir():
        shutil.copytree(trimmed, SITE / "gymnasium_robotics", dirs_exist_ok=True)
    sys.path.insert(0, str(SITE))
    print(f"installed {len(list(wheels.glob('*.whl')))} wheels into {SITE}", flush=True)


def child_env() -> dict:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    paths = [str(SITE)] if SITE.is_dir() else []
    paths += [str(REPO), *filter(None, [env.get("PYTHONPATH")])]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


def run_step(name: str, cmd: list[str], limit_s: float, log: Log, cpus: set[int] | None = None,
             cwd: Path = REPO) -> tuple[int | None, float, float, str]:
    """Run one command in ``cwd`` with a time limit (on the cores ``cpus`` only, if given):
    (exit status or None when killed at the limit, wall s, peak PSS MB, its output). Its output
    goes to the log as it comes."""
    from bench import _tree_pss_mb as tree_pss_mb  # (studies/ is this script's folder)

    log(f"\n=== {name}: {' '.join(cmd)} (limit {limit_s:.0f} s"
        + (f", cores {min(cpus)}-{max(cpus)})" if cpus else ")"))
    t = time.perf_counter()
    pin = (lambda: os.sched_setaffinity(0, cpus)) if cpus else None
    proc = subprocess.Popen(cmd, cwd=cwd, env=child_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=pin)
    lines: list[str] = []

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            log(f"[{name}] {line.rstrip()}")

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    peak = 0.0
    while proc.poll() is None and time.perf_counter() - t < limit_s:
        peak = max(peak, tree_pss_mb(proc.pid))
        time.sleep(0.25)
    status = proc.poll()
    if status is None:
        os.killpg(proc.pid, 9)
        proc.wait()
        log(f"=== {name}: killed at its {limit_s:.0f} s limit")
    reader.join(5)
    wall = time.perf_counter() - t
    log(f"=== {name}: exit {status}, {wall:.1f} s, peak {peak:,.0f} MB")
    return status, wall, peak, "".join(lines)


def progress(run_root: Path) -> list[dict]:
    """The rows of the one run folder's tb/progress.csv under run_root (empty if none yet)."""
    files = sorted(run_root.glob("*/tb/progress.csv"))
    if not files:
        return []
    with open(files[0]) as f:
        return list(csv.DictReader(f))


def train_cmd(*flags: str) -> list[str]:
    return [sys.executable, str(REPO / "train.py"), "--no-progress", *flags]


def machine(log: Log) -> dict:
    code = ("import json, os, platform, torch, mujoco, stable_baselines3 as sb3;"
            "g = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None;"
            "print('MACHINE ' + json.dumps(dict(python=platform.python_version(), cores=os.cpu_count(),"
            "torch=torch.__version__, cuda=torch.version.cuda, gpu=g, mujoco=mujoco.__version__,"
            "sb3=sb3.__version__)))")
    status, _, _, out = run_step("machine", [sys.executable, "-c", code], 120, log)
    info = next((json.loads(x[8:]) for x in out.splitlines() if x.startswith("MACHINE ")), {})
    with open("/proc/cpuinfo") as f:
        info["cpu"] = next((x.split(":", 1)[1].strip() for x in f if "model name" in x), "?")
    return info


def test_quality() -> None:
    """The --test-quality table (see Args.test_quality)."""
    import numpy as np
    from runs import KEYS, TEST, _metrics_on_test

    from panda_lead import harness
    from panda_lead.metrics.stats import paired_ci, t_ci
    from panda_lead.summaries import read_json

    names = {"mean_err": "mean error (cm)", "settled_err": "settled error (cm)",
             "jerk_rms": "jerk RMS (m/s^3)"}
    models = {int(f.stem.rsplit("_s", 1)[1]): f
              for f in (REPO / "archive" / "seeds").glob("gpu_profile_5m_s*.zip")}
    print(f"Test seeds {TEST}, 5 s episodes: the gpu profile's best model (evaluation set, "
          "every 250k steps) against the 2-core default's (`curriculum_5m`) of the same training "
          "seed; differences gpu - default, paired by trajectory, 95% bootstrap CIs. "
          "`uv run studies/device_plan.py --test-quality`\n")
    print("| seed | metric | gpu profile | 2-core default | difference [95% CI] |")
    print("|---|---|---|---|---|")
    per_seed = {k: [] for k in KEYS}  # (gpu, default) study means, one pair per training seed
    for seed in sorted(models):
        ctrl = harness.build("policy", 500, models[seed])
        gpu = _metrics_on_test(ctrl)
        cpu = read_json(REPO / "results" / "runs" / "curriculum_5m" / f"seed_{seed}.json",
                        "a run summary")["test"]
        for k in KEYS:
            a, b = np.array(gpu[k]), np.array(cpu[k])
            lo, hi = paired_ci(a - b)
            per_seed[k].append((a.mean(), b.mean()))
            print(f"| {seed} | {names[k]} | {a.mean():.3f} | {b.mean():.3f} | "
                  f"{(a - b).mean():+.3f} [{lo:+.3f}, {hi:+.3f}] |", flush=True)
    means = [np.mean(read_json(f, "a run summary")["test"]["mean_err"])
             for f in sorted((REPO / "results" / "runs" / "curriculum_5m").glob("seed_*.json"))]
    print(f"\nThe 2-core default's {len(means)} seeds: test mean error {min(means):.2f}-"
          f"{max(means):.2f} cm (mean {np.mean(means):.2f}).")
    if len(models) >= 3:
        print(f"\nAcross the {len(models)} training seeds (each seed's test mean, gpu - default "
              "paired by training seed; 95% t interval over seeds):\n")
        print("| metric | gpu profile | 2-core default | difference [95% CI] |\n|---|---|---|---|")
        for k in KEYS:
            g, c = (np.array(x) for x in zip(*per_seed[k], strict=True))
            lo, hi = t_ci(g - c)
            print(f"| {names[k]} | {g.mean():.3f} ± {g.std(ddof=1):.3f} | {c.mean():.3f} ± "
                  f"{c.std(ddof=1):.3f} | {(g - c).mean():+.3f} [{lo:+.3f}, {hi:+.3f}] |")


def quality_curves() -> None:
    """The --curves table (see Args.curves)."""
    from panda_lead.summaries import read_json

    def grid(curve):  # the 2-core runs evaluated every 50,016 steps: every fifth is the grid
        return [(t, e) for t, e in curve if (t // 50_016) % 5 == 0]

    def row(name: str, curves: list) -> str:
        by3 = ", ".join(f"{min(e for t, e in c if t <= 3.01e6):.2f}" for c in curves)
        by5 = ", ".join(f"{min(e for _, e in c):.2f}" if c[-1][0] > 4.7e6 else "-" for c in curves)
        hit = ", ".join(next((f"{t / 1e6:.2f}M" for t, e in c if e < 2.5), "-") for c in curves)
        return f"| {name} | {by3} | {by5} | {hit} |"

    runs = REPO / "results" / "runs" / "curriculum_5m"
    cpu = [grid(read_json(f, "a run summary")["eval_curve"]) for f in sorted(runs.glob("seed_*.json"))]
    print("Evaluation-set error (cm) on a 250k-step grid, per training seed. "
          "`uv run studies/device_plan.py --curves`\n")
    print("| configuration | best by 3M steps | best by 5M | steps to 2.5 cm |\n|---|---|---|---|")
    print(row("2-core default (curriculum_5m, seeds 1-5)", cpu))
    for name, stem in (("128 envs x 128, batch 4,096", "gpu128_b4096"),
                       ("gpu profile: 256 envs x 128, batch 8,192", "gpu256_b8192")):
        kept = {int(f.name.split("_s")[-1].split("_")[0]): f  # .../<stem>_s<seed>_progress.csv
                for f in REPO.glob(f"results/bench/device_2026-11-2*/{stem}_s*_progress.csv")}
        curves = []
        for seed in sorted(kept):
            with open(kept[seed]) as f:
                curves.append([(int(float(r["eval/timesteps"])), float(r["eval/mean_error_cm"]))
                               for r in csv.DictReader(f) if r.get("eval/mean_error_cm")])
        print(row(f"{name} (seeds {', '.join(map(str, sorted(kept)))})", curves))


def main() -> None:
    t_start = time.perf_counter()
    wheels = wheels_given(sys.argv[1:])
    if wheels:
        install_wheels(wheels)
    sys.path.insert(0, str(REPO))  # the device has no installed panda_lead: the checkout's
    from panda_lead.errors import exit_on_user_error

    exit_on_user_error(plan)(t_start)


def plan(t_start: float) -> None:
    from panda_lead.errors import parse_cli

    args = parse_cli(Args, description=__doc__)
    if args.test_quality:
        return test_quality()
    if args.curves:
        return quality_curves()
    args.out.mkdir(parents=True, exist_ok=True)
    log = Log(args.out / "log.txt")
    info = machine(log)
    log(f"machine: {info}")
    cuda = "cuda" if info.get("gpu") else "cpu"  # the dry run has no GPU: the same steps on cpu
    cores = info.get("cores") or os.cpu_count() or 1
    work = Path(tempfile.mkdtemp(prefix="device_plan_"))
    rows: list[tuple[str, str]] = []
    artifacts: list[tuple[Path, str]] = []

    def row(name: str, value: str) -> None:
        rows.append((name, value))
        log(f"ROW {name}: {value}")

    small = ["--n-envs", "8", "--n-steps", "64", "--batch-size", "256"] if args.small else []
    if not args.quality_only:
        steps_2_to_4(args, log, work, cuda, small, row, artifacts)
    elif args.cprofile:
        gpu_cprofile(args, log, cuda)
    quality(args, log, work, cuda, cores, small, row, artifacts)
    finish(args, log, info, cores, rows, artifacts, t_start)


def steps_2_to_4(args, log, work, cuda, small, row, artifacts) -> None:
    # 2. --device cuda end to end: train with the profile it picks, resume, archive.
    e2e = work / "e2e"
    one = 512 if args.small else 16384  # one rollout of the profile's collection
    archived = f"{cuda}_e2e"  # cuda_e2e into the device's checkout
    # A dry run (no GPU) archives into its scratch folder: it leaves the checkout's archive/
    # as it was, and two dry runs at once (the slow tests on two workers) never meet there.
    home = REPO if cuda == "cuda" else work
    status, _, _, _ = run_step("e2e_train", train_cmd(
        "--device", cuda, *small, "--timesteps", str(2 * one), "--eval-freq", str(one),
        "--checkpoint-freq", str(one), "--runs-dir", str(e2e), "--name", archived,
        "--seed", "7"), 120, log, cwd=home)
    runs = sorted(e2e.glob(f"{archived}*"))
    if status == 0 and runs:
        status, _, _, _ = run_step("e2e_resume_archive", train_cmd(
            "--resume", str(runs[0]), "--timesteps", str(4 * one), "--device", cuda,
            "--archive", archived, "--force"), 120, log, cwd=home)
    shipped = [home / "archive" / f"{archived}{suffix}" for suffix in (".zip", ".json", ".md")]
    artifacts += [(f, f"archive/{f.name}") for f in shipped if status == 0 and f.is_file()]
    row(f"`--device {cuda}` end to end: train {2 * one:,} steps (the profile `--device` picks), "
        f"resume to {4 * one:,}, archive", "ok" if status == 0 else f"failed (exit {status}; log.txt)")

    # 3. The env alone.
    bench = [sys.executable, str(REPO / "studies" / "bench.py"), "--env-only", "--repeats", "3",
             "--out", str(args.out / "bench_env.md")] + (["--quick"] if args.small else [])
    status, _, _, out = run_step("bench_env", bench, 150, log)
    for line in out.splitlines():
        if line.startswith("| ") and not line.startswith(("| figure", "|---")):
            name, value = [c.strip() for c in line.strip("|").split("|", 1)]
            row(name, value)

    # 4. PPO samples/s through train.py.
    it_default = 32 * 128
    candidates = [  # name, flags, steps
        ("reference configuration (8 SubprocVecEnv, n_steps 1024, batch 64), CPU learner",
         ["--reference-hparams"], 3 * 8192),
        ("2-core default (32 envs x 128 steps, batch 1,024), CPU learner",
         ["--profile", "cpu"], 40 * it_default),
        ("2-core default, CUDA learner", ["--profile", "cpu", "--device", cuda], 40 * it_default),
        ("128 envs x 128 steps, batch 1,024, CPU learner", ["--profile", "cpu", "--n-envs", "128"],
         12 * 16384),
        ("128 envs x 128 steps, batch 1,024, CUDA learner",
         ["--profile", "gpu", "--device", cuda, "--batch-size", "1024"], 12 * 16384),
        ("gpu profile: 128 envs x 128 steps, batch 4,096, CUDA learner",
         ["--profile", "gpu", "--device", cuda], 12 * 16384),
        ("256 envs x 128 steps, batch 8,192, CUDA learner",
         ["--profile", "gpu", "--device", cuda, "--n-envs", "256", "--batch-size", "8192"],
         6 * 32768),
    ]
    rates = {}
    for name, flags, steps in candidates:
        if args.small:
            flags = [*flags, "--n-envs", "8", "--n-steps", "64", "--batch-size", "256"]
            steps = 2048
        root = work / f"ppo{len(rates)}"
        status, wall, peak, _ = run_step(name, train_cmd(
            *flags, "--timesteps", str(steps), "--eval-freq", "0", "--checkpoint-freq",
            str(10**9), "--runs-dir", str(root), "--seed", "1"),
            300 if args.small else 75 if not rates else 60, log)  # small: 2 slow cores
        rows_ = progress(root)
        fps = next((float(r["time/fps"]) for r in reversed(rows_) if r.get("time/fps")), None)
        done = next((int(float(r["time/total_timesteps"])) for r in reversed(rows_)
                     if r.get("time/total_timesteps")), 0)
        rates[name] = fps
        if fps:
            row(f"PPO samples/s, {name}", f"{fps:,.0f} ({done:,} steps; 5M in "
                f"{5e6 / fps / 60:.1f} min; peak {peak:,.0f} MB; process {wall:.0f} s)")
        else:
            row(f"PPO samples/s, {name}", f"no figure (exit {status}; log.txt)")
    ref = rates[candidates[0][0]]
    if ref:
        for name, _, _ in candidates[1:]:
            if rates[name]:
                row(f"ratio to the reference configuration: {name}", f"{rates[name] / ref:.1f}x")



def gpu_cprofile(args, log, cuda) -> None:
    """Where a sample's time goes in the gpu profile: issue 41's missing profile."""
    cmd = [sys.executable, str(REPO / "studies" / "profile_update.py"), "--variants", "fast",
           "--cprofile", str(args.cprofile)]
    cmd += ["--quick"] if args.small else ["--train-profile", "gpu" if cuda == "cuda" else "cpu"]
    _, _, _, out = run_step("cprofile_gpu", cmd, 150, log)
    (args.out / "cprofile_gpu.txt").write_text(out)


def quality(args, log, work, cuda, cores, small, row, artifacts) -> None:
    # 5. Quality: the gpu profile, 5M steps, the runs at once on an equal share of the cores:
    # one per training seed, or one per --quality-variants entry.
    steps = 40_960 if args.small else args.quality_steps
    every = 8192 if args.small else args.quality_eval_freq
    variants = [v.strip() for v in args.quality_variants.split(";") if v.strip()]
    runs = ([(f"v{i + 1}", v.split(), v) for i, v in enumerate(variants)] if variants else
            [(f"s{seed}", ["--seed", str(seed)], f"seed {seed}") for seed in args.quality_seeds])
    share = max(1, cores // len(runs))
    threads: list[threading.Thread] = []
    results: dict[str, tuple] = {}
    for i, (key, own, _) in enumerate(runs):
        cpus = set(range(i * share, i * share + share)) if cores >= len(runs) else None
        flags = ["--profile", "gpu", "--device", cuda, "--n-workers", str(share),
                 *args.quality_flags.split(), *own, *small]
        cmd = train_cmd(*flags, "--timesteps", str(steps), "--eval-freq", str(every),
                        "--checkpoint-freq", str(10**9), "--runs-dir", str(work / f"q{key}"),
                        "--name", "quality")
        th = threading.Thread(target=lambda k=key, c=cmd, p=cpus: results.__setitem__(
            k, run_step(f"quality_{k}", c, args.quality_limit_s, log, p)))
        th.start()
        threads.append(th)
    for th in threads:
        th.join()
    for key, _, label in runs:
        rows_ = progress(work / f"q{key}")
        curve = [(int(float(r["eval/timesteps"])), float(r["eval/mean_error_cm"]))
                 for r in rows_ if r.get("eval/mean_error_cm")]
        status = results[key][0]
        named = f"gpu profile {args.quality_flags}".strip() + f", {label}"
        if curve:
            best = min(e for _, e in curve)
            row(f"quality, {named} (evaluation set, every {every:,} steps)",
                f"best {best:.2f} cm, last {curve[-1][1]:.2f} cm at {curve[-1][0]:,} steps "
                f"({'finished' if status == 0 else 'cut at the time limit'}, "
                f"{results[key][1]:.0f} s); curve " + " ".join(f"{e:.2f}" for _, e in curve))
        else:
            row(f"quality, {named}", f"no evaluation (exit {status}; log.txt)")
        for run in (work / f"q{key}").glob("*"):
            # What `studies/runs.py summarize` reads of a run folder, so a run can join a study.
            for rel in ("tb/progress.csv", "config.json", "command.txt", "best.json",
                        "best_model.zip", "best_model.json", "final_model.zip", "final_model.json"):
                if (run / rel).is_file():
                    artifacts.append((run / rel, f"quality_{key}/{rel.replace('/', '_')}"))


def finish(args, log, info, cores, rows, artifacts, t_start) -> None:
    total = time.perf_counter() - t_start
    head = (f"`python3 studies/device_plan.py{' --small' if args.small else ''}` on {cores} cores "
            f"({info.get('cpu')}), GPU {info.get('gpu')}, {time.strftime('%Y-%m-%d')}, Python "
            f"{info.get('python')}, torch {info.get('torch')} (CUDA {info.get('cuda')}), mujoco "
            f"{info.get('mujoco')}, SB3 {info.get('sb3')}; the whole plan {total:.0f} s")
    table = "\n".join([head, "", "| figure | value |", "|---|---|",
                       *[f"| {k} | {v} |" for k, v in rows]])
    (args.out / "table.md").write_text(table + "\n")
    with tarfile.open(args.out / "artifacts.tar.gz", "w:gz") as tar:
        for path, name in artifacts:
            tar.add(path, arcname=name)
    log("\n" + table)


if __name__ == "__main__":
    main()
