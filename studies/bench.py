"""Speed and memory figures: `uv run studies/bench.py` (about 5 minutes on 2 cores).

Every figure is the median of repeats. Printed as a markdown table with the machine, the date
and the command, ready for the README. `--quick` shortens everything (for a smoke test).
"""

from __future__ import annotations

import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    repeats: int = 7
    """Repeats per micro-benchmark (the median is reported)."""
    max_workers: int = 0
    """Largest MuJoCo thread count for the batched figures (0: the number of cores)."""
    ppo_iterations: int = 4
    """PPO iterations timed per configuration (after one warm-up iteration)."""
    quick: bool = False
    """Tiny budgets, for a smoke test of the script itself."""
    out: Path | None = None
    """Also write the markdown table to this file."""
    step_pairs: int = 0
    """Only the per-step ratio: time raw physics and the batched env step back to back this
    many times and print each ratio and their median (steadier than one pair on a shared
    machine, whose speed drifts between the start and the end of a full run)."""
    update_pairs: int = 0
    """Only issue 39's before/after: `train.py` with its defaults (FastPPO's update) and with
    `--no-fast-update` (SB3's own), --update-steps each, back to back this many times: each
    pair's samples/s, wall ratio and peak memory (PSS, whole process tree), then the medians."""
    update_steps: int = 300_000
    """Training steps per run of --update-pairs and --parallel-pairs."""
    update_against: str = "--no-fast-update"
    """--update-pairs' second run: the defaults plus these flags, one string after an =
    (--update-against="--n-envs 256 --batch-size 8192": a larger collection and minibatch)."""
    update_base: str = ""
    """Flags for both runs of --update-pairs, one string after an = (--update-base="--preset
    deploy_caps_armfilter")."""
    env_only: bool = False
    """Only the env's figures (physics, single env, batched env per thread and on every
    thread, the physics-bound limit): no PPO, no memory run (studies/device_plan.py times PPO
    through train.py itself)."""
    parallel_pairs: int = 0
    """Only the runs-per-hour figure: `train.py` with its defaults alone, then --parallel-runs
    copies of it at once (the same flags, other seeds), --update-steps each, this many times:
    the machine's samples/s over all the runs against one run's (a sweep's --workers)."""
    parallel_runs: int = 0
    """Runs at once for --parallel-pairs (0: one per core)."""
    parallel_flags: str = ""
    """Extra train.py flags for every run of --parallel-pairs, one string after an =:
    --parallel-flags="--n-workers 1"."""
    single_pairs: int = 0
    """Only the single env's ratio, the same way: raw physics and a gymnasium.make step (400
    random-action steps, median of 3 each) back to back this many times, each ratio and their
    median (docs/performance.md, "The single env")."""


def print_pairs(count: int, label: str, pair) -> None:
    """``count`` back-to-back (raw physics us, step us) pairs from ``pair()``: each ratio, then
    their median (steadier than one pair on a shared machine, whose speed drifts)."""
    ratios = []
    for _ in range(count):
        physics, step = pair()
        ratios.append(step / physics)
        print(f"raw physics {physics:.1f} us, {label} {step:.1f} us: {step / physics:.2f}x",
              flush=True)
    print(f"median of {len(ratios)} pairs: {statistics.median(ratios):.2f}x physics "
          f"(range {min(ratios):.2f}-{max(ratios):.2f})")


def update_pairs(count: int, steps: int, base: tuple[str, ...] = (),
                 against: tuple[str, ...] = ("--no-fast-update",)) -> None:
    """Issue 39's before/after on whole `train.py` runs (see Args.update_pairs): the defaults
    (plus ``base``) against the same plus ``against``."""
    b_name = "SB3's update" if against == ("--no-fast-update",) else " ".join(against)
    a_name = "FastPPO" if b_name == "SB3's update" else "defaults"
    if base:
        a_name += f" ({' '.join(base)})"
    ratios, mem = [], {"a": [], "b": []}
    for i in range(count):
        (a_mb, a_s), (b_mb, b_s) = bench_memory(steps, base), bench_memory(steps, (*base, *against))
        ratios.append(b_s / a_s)
        mem["a"].append(a_mb)
        mem["b"].append(b_mb)
        print(f"pair {i + 1}: {a_name} {steps / a_s:,.0f} samples/s ({a_s:.1f} s, peak "
              f"{a_mb:,.0f} MB), {b_name} {steps / b_s:,.0f} samples/s ({b_s:.1f} s, "
              f"peak {b_mb:,.0f} MB): {a_name} at {b_s / a_s:.3f}x {b_name}'s samples/s",
              flush=True)
    a_mb, b_mb = statistics.median(mem["a"]), statistics.median(mem["b"])
    print(f"median of {count} pairs: {a_name} at {statistics.median(ratios):.3f}x {b_name}'s "
          f"samples/s (range {min(ratios):.3f}-{max(ratios):.3f}); peak memory {a_mb:,.0f} MB "
          f"against {b_mb:,.0f} MB (medians). Wall times include each process's start (torch "
          "import, env build), the same for both.")


def _train_cmd(tmp: str, timesteps: int, extra: tuple[str, ...]) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve().parents[1] / "train.py"), "--timesteps",
            str(timesteps), "--runs-dir", tmp, "--no-progress", "--eval-freq", "0", *extra]


def bench_runs_at_once(runs: int, timesteps: int, extra: tuple[str, ...]) -> float:
    """Wall s for ``runs`` train.py processes started together (training seeds 1..runs), until
    the last ends; each run's own wall includes its process start."""
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        # stderr to files: a pipe nobody reads until the end blocks a run that fills it
        errs = [Path(tmp) / f"stderr_{k}" for k in range(runs)]
        procs = [subprocess.Popen(_train_cmd(tmp, timesteps, (*extra, "--seed", str(k + 1))),
                                  cwd=tmp, stdout=subprocess.DEVNULL, stderr=errs[k].open("wb"))
                 for k in range(runs)]
        try:
            for proc, err in zip(procs, errs, strict=True):
                if proc.wait() != 0:
                    raise RuntimeError(f"train.py failed: {err.read_text()[-2000:]}")
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        return time.perf_counter() - t


def parallel_pairs(count: int, runs: int, steps: int, extra: tuple[str, ...]) -> None:
    """Samples per second of the whole machine: one run alone, then ``runs`` at once (see
    Args.parallel_pairs)."""
    ratios = []
    for i in range(count):
        alone = bench_runs_at_once(1, steps, extra)
        together = bench_runs_at_once(runs, steps, extra)
        ratios.append(runs * alone / together)
        print(f"pair {i + 1}: one run {steps / alone:,.0f} samples/s ({alone:.1f} s); {runs} at "
              f"once {runs * steps / together:,.0f} samples/s in all ({together:.1f} s until the "
              f"last ended): {ratios[-1]:.2f}x the samples per hour", flush=True)
    print(f"median of {count} pairs: {runs} runs at once give {statistics.median(ratios):.2f}x "
          f"one run's samples per hour (range {min(ratios):.2f}-{max(ratios):.2f}); flags: "
          f"{' '.join(extra) or 'the defaults'}. Wall times include each process's start.")


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def bench_physics(n: int, repeats: int) -> float:
    """Microseconds for 5 x mj_step of the scene (one env step's worth of physics), one
    MjData, the arm moving (a sinusoidal joint goal), as the envs do."""
    import mujoco

    from panda_lead.core import home_qpos, load_model

    m = load_model()
    d = mujoco.MjData(m)
    home = home_qpos()
    goals = home + 0.3 * np.sin(np.arange(n)[:, None] * 0.05 + np.arange(7))

    def run():
        mujoco.mj_resetDataKeyframe(m, d, 0)
        for g in goals:
            d.ctrl[:7] = g
            mujoco.mj_step(m, d, 5)

    run()
    return median_time(run, repeats) / n * 1e6


def bench_single_env(n: int, repeats: int) -> float:
    """Microseconds per step through gymnasium.make (all wrappers), random actions."""
    import gymnasium as gym

    import panda_lead  # noqa: F401  (registers PandaLead-v0)

    e = gym.make("PandaLead-v0", episode_steps=n + 1, max_episode_steps=n + 1)
    actions = np.random.default_rng(0).uniform(-1, 1, (n, 3)).astype(np.float32)

    def run():
        e.reset(seed=0)
        for a in actions:
            e.step(a)

    run()
    return median_time(run, repeats) / n * 1e6


def bench_batched(n_envs: int, threads: int, steps: int, repeats: int, **settings
                  ) -> tuple[float, float]:
    """(CPU us per env step, wall env steps/s) of the SB3 view of the batched env (what PPO
    steps: IK, physics, contacts, reward, observation, in-step resets), random actions;
    ``settings`` are EnvConfig fields."""
    from panda_lead.config import EnvConfig
    from panda_lead.sb3_vecenv import LeadVecEnv

    vec = LeadVecEnv(EnvConfig(**settings), n_envs, nthread=threads)
    vec.seed(0)
    vec.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, n_envs, 3)).astype(np.float32)
    cpu, wall = [], []
    for _ in range(repeats):
        c, t = time.process_time(), time.perf_counter()
        for a in actions:
            vec.step_async(a)
            vec.step_wait()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - t)
    total = steps * n_envs
    return statistics.median(cpu) / total * 1e6, total / statistics.median(wall)


def bench_subproc(n_envs: int, seconds: float) -> float:
    """Env steps per second of SB3's SubprocVecEnv (a process per env), random actions."""
    from panda_lead.training import make_vec_env

    vec = make_vec_env({}, n_envs, 0, "subproc")
    vec.reset()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (64, n_envs, 3)).astype(np.float32)
    for a in actions[:10]:
        vec.step(a)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        vec.step(actions[steps % 64])
        steps += 1
    rate = steps * n_envs / (time.perf_counter() - t0)
    vec.close()
    return rate


def reference() -> dict:
    from panda_lead.training import REFERENCE_HPARAMS

    return dict(REFERENCE_HPARAMS)


def bench_ppo(config: dict, iterations: int, torch_threads: int) -> float:
    """Samples per second of full PPO (collection + update), after one warm-up iteration."""
    import torch
    from stable_baselines3 import PPO

    from panda_lead.training import make_vec_env

    torch.set_num_threads(torch_threads)
    vec = make_vec_env({}, config["n_envs"], 0, config["vec_env"], config.get("n_workers", 0))
    model = PPO("MlpPolicy", vec, n_steps=config["n_steps"], batch_size=config["batch_size"],
                n_epochs=config["n_epochs"], learning_rate=config["learning_rate"], device="cpu",
                seed=0, policy_kwargs=dict(activation_fn=torch.nn.Tanh,
                                           log_std_init=config["log_std_init"]))
    per_iter = config["n_steps"] * config["n_envs"]
    model.learn(per_iter)
    t = time.perf_counter()
    model.learn(per_iter * iterations, reset_num_timesteps=False)
    rate = per_iter * iterations / (time.perf_counter() - t)
    vec.close()
    return rate


def _tree_pss_mb(pid: int) -> float:
    """Proportional set size of a process and all its descendants (Linux /proc): shared pages
    (torch, MuJoCo) count once in total, not once per worker as RSS would."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/smaps_rollup") as f:
                total += next(int(line.split()[1]) for line in f if line.startswith("Pss:"))
            with open(f"/proc/{p}/task/{p}/children") as f:
                stack.extend(int(c) for c in f.read().split())
        except (OSError, StopIteration):
            continue
    return total / 1024


def bench_memory(timesteps: int, extra: tuple[str, ...] = ()) -> tuple[float, float]:
    """Peak memory (MB, PSS) of `train.py` with its defaults (plus ``extra`` flags), whole
    process tree; and wall s."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = _train_cmd(tmp, timesteps, extra)
        err = Path(tmp) / "stderr"  # a file: a pipe read only at the end blocks a run that fills it
        t = time.perf_counter()
        with err.open("wb") as sink:
            proc = subprocess.Popen(cmd, cwd=tmp, stdout=subprocess.DEVNULL, stderr=sink)
            try:
                peak = 0.0
                while proc.poll() is None:
                    peak = max(peak, _tree_pss_mb(proc.pid))
                    time.sleep(0.1)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        if proc.returncode != 0:
            raise RuntimeError(f"train.py failed: {err.read_text()[-2000:]}")
        return peak, time.perf_counter() - t


def cpu_model() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if "model name" in line)
    except (OSError, StopIteration):
        pass
    return cpu


def repo_default() -> dict:
    from panda_lead.training import TrainConfig

    a = TrainConfig()
    return dict(n_envs=a.n_envs, vec_env=a.vec_env, n_workers=a.n_workers, n_steps=a.n_steps,
                batch_size=a.batch_size, n_epochs=a.n_epochs, learning_rate=a.learning_rate,
                log_std_init=a.log_std_init, torch_threads=a.torch_threads)


def main() -> None:
    args = parse_cli(Args, description=__doc__)
    cores = os.cpu_count() or 1
    max_workers = args.max_workers or cores
    reps = 3 if args.quick else args.repeats
    n = 200 if args.quick else 2000
    secs = 0.5 if args.quick else 2.0
    rows: list[tuple[str, str]] = []
    if args.update_pairs:
        return update_pairs(args.update_pairs, args.update_steps,
                            tuple(shlex.split(args.update_base)),
                            tuple(shlex.split(args.update_against)))
    if args.parallel_pairs:
        return parallel_pairs(args.parallel_pairs, args.parallel_runs or cores, args.update_steps,
                              tuple(shlex.split(args.parallel_flags)))
    if args.single_pairs:
        return print_pairs(args.single_pairs, "single env step via gymnasium.make",
                           lambda: (bench_physics(400, 3), bench_single_env(400, 3)))
    if args.step_pairs:
        return print_pairs(args.step_pairs, "batched env step (64 envs, 1 thread)",
                           lambda: (bench_physics(n, reps), bench_batched(64, 1, 200, reps)[0]))

    def row(name: str, value: str) -> None:
        rows.append((name, value))
        print(f"{name}: {value}", flush=True)

    physics = bench_physics(n, reps)
    row("raw physics, 5 x mj_step (one env step), one MjData", f"{physics:.1f} us")
    single = bench_single_env(n, reps)
    row("single env step via gymnasium.make", f"{single:.1f} us ({single / physics:.2f}x physics)")
    steps = 20 if args.quick else 200
    cpu1, rate1 = bench_batched(64, 1, steps, reps)
    row("batched env (64 envs, 1 thread): CPU per env step",
        f"{cpu1:.1f} us ({cpu1 / physics:.2f}x physics)")
    cpu_aware, _ = bench_batched(64, 1, steps, reps, ik={"clearance": 0.02})
    row("batched env (64 envs, 1 thread), collision-aware IK (--env.ik.clearance 0.02)",
        f"{cpu_aware:.1f} us (+{cpu_aware - cpu1:.1f} us, {cpu_aware / cpu1:.2f}x the plain IK)")
    n_big = 256
    _, base = bench_batched(n_big, 1, steps // 2, reps)
    row(f"batched env, {n_big} envs, 1 thread", f"{base:,.0f} env steps/s")
    for threads in sorted({t for t in (2, 4, 8, 16) if t <= max_workers} | {max_workers}):
        if threads == 1:
            continue
        _, rate = bench_batched(n_big, threads, steps // 2, reps)
        row(f"batched env, {n_big} envs, {threads} threads",
            f"{rate:,.0f} env steps/s ({rate / base:.2f}x one thread; target >= "
            f"{0.7 * threads:.1f}x)")
    if max_workers >= 8:  # 16 envs per thread are too few to fill a many-core machine
        _, rate = bench_batched(4 * n_big, max_workers, steps // 4, reps)
        row(f"batched env, {4 * n_big} envs, {max_workers} threads",
            f"{rate:,.0f} env steps/s ({rate / base:.2f}x one thread at {n_big} envs)")
    row(f"physics-bound limit, {cores} cores (cores x 1 / raw physics)",
        f"{cores * 1e6 / physics:,.0f} env steps/s")
    if args.env_only:
        return finish(args, rows, cores)
    rate = bench_subproc(max_workers, secs)
    row(f"SB3 SubprocVecEnv, {max_workers} envs ({max_workers} processes)", f"{rate:,.0f} env steps/s")
    iters = 1 if args.quick else args.ppo_iterations
    ref = dict(reference(), n_steps=128) if args.quick else reference()
    default = repo_default()
    if args.quick:
        default["n_steps"] = 64
    # The reference ran SB3 as it comes: torch takes one thread per core. This repo's train.py
    # uses one (--torch-threads); the reference is also timed that way, to separate the effects.
    ref_rate = bench_ppo(ref, iters, cores)
    row(f"PPO samples/s, reference (8 SubprocVecEnv, batch 64, n_steps 1024, {cores} torch "
        "threads)", f"{ref_rate:,.0f}")
    ref1_rate = bench_ppo(ref, iters, 1)
    row("PPO samples/s, reference with 1 torch thread",
        f"{ref1_rate:,.0f} ({ref1_rate / ref_rate:.1f}x reference)")
    threads = default.pop("torch_threads")
    def_rate = bench_ppo(default, iters, threads)
    desc = ", ".join(f"{k} {v}" for k, v in default.items() if k in (
        "n_envs", "vec_env", "n_steps", "batch_size", "n_epochs"))
    row(f"PPO samples/s, repo default ({desc}, {threads} torch thread)",
        f"{def_rate:,.0f} ({def_rate / ref_rate:.1f}x reference)")
    peak, wall = bench_memory(20_000 if args.quick else 100_000)
    row("peak memory of `train.py` (defaults, whole process tree, PSS)", f"{peak:,.0f} MB")
    finish(args, rows, cores)


def finish(args: Args, rows: list[tuple[str, str]], cores: int) -> None:
    """Print the rows as a markdown table headed by the command, machine and date."""
    cpu = cpu_model()
    # The command as it was launched: `uv run` sets UV; on the device it runs as python3.
    launcher = ["uv", "run"] if "UV" in os.environ else ["python3"]
    header = (f"`{shlex.join([*launcher, 'studies/bench.py', *sys.argv[1:]])}` on {cores} cores "
              f"({cpu}), {time.strftime('%Y-%m-%d')}, Python {platform.python_version()}")
    table = "\n".join([header, "", "| figure | value |", "|---|---|",
                       *[f"| {k.strip()} | {v} |" for k, v in rows]])
    print("\n" + table)
    if args.out:
        args.out.write_text(table + "\n")


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(main)()
