"""Profile of one default training iteration: where a PPO sample's time goes.

    uv run studies/profile_update.py                  # SB3's PPO against FastPPO, 3 pairs
    uv run studies/profile_update.py --pairs 5 --iterations 6
    uv run studies/profile_update.py --variants fast --cprofile 2   # where a sample's time goes
    uv run studies/profile_update.py --activations 2000   # tanh's kernel against its neighbours
    python3 studies/profile_update.py --variants fast --cprofile 5 --train-profile gpu  # on a GPU

Times PPO iterations of the repo default (TrainConfig(): 32 batched envs x 128 steps, batch
1,024, 10 epochs, one torch thread) with timers around the parts SB3 calls: the env step, the
policy's forward pass while collecting, the rest of SB3's collection loop, and in the update
the minibatch forward pass, backward, gradient clipping, the optimiser, and the rest (loss
arithmetic, minibatch copies, per-minibatch logging); then the logger's dump. Each figure is
microseconds per collected sample. Beside them: the physics-bound limit, the raw physics of
one env step (5 x mj_step) spread over the machine's cores.

On a shared machine the variants run interleaved (A, B, B, A, ...) in one process and the
table gives the median over the pairs of each part and the median of the paired ratios.
"""

from __future__ import annotations

import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from panda_lead.errors import UserError, exit_on_user_error, parse_cli

PARTS = ["env step (IK, physics, reward)", "policy forward (collection)",
         "SB3 collection loop (rest)", "update: forward", "update: backward",
         "update: clip grad norm", "update: optimiser (Adam, zero_grad)",
         "update: rest (loss, minibatch copies, logging)", "logger dump, callbacks, other"]


@dataclass
class Args:
    variants: list[str] = field(default_factory=lambda: ["sb3", "fast"])
    """sb3 (stable-baselines3's PPO as it comes), fast (FastPPO), fast2 (FastPPO with 2 torch
    threads during the update), sigtanh (a what-if, not a training option: FastPPO with the
    network's tanh computed as 2 sigmoid(2x) - 1, which torch runs ~5x faster on this CPU;
    not bit-identical to torch.tanh)."""
    pairs: int = 3
    """Rounds; each round times every variant once, the order alternating between rounds."""
    iterations: int = 4
    """PPO iterations timed per variant per round (after one warm-up iteration)."""
    quick: bool = False
    """Tiny budgets (n_steps 16), for a smoke test."""
    update_only: int = 0
    """Only the update: this many rounds of one PPO update (train()) per variant on the same
    collected rollout, interleaved; wall and CPU ms per update, their medians and ratios."""
    cprofile: int = 0
    """Only a cProfile: this many PPO iterations of the first variant, the functions with the
    most own time and those that cost a sample's wall time (MuJoCo's rollout, the env step,
    the policy's forward, the update), in us per sample."""
    activations: int = 0
    """Only the activation micro-benchmark: this many calls per round (5 rounds, median) of
    torch.tanh, torch.sigmoid, the sigtanh what-if, numpy's tanh and the 64 x 64 matmul beside
    them, on 1,024 x 64 floats (a minibatch's hidden layer), one torch thread."""
    train_profile: str = "cpu"
    """The machine profile to profile (training/config.py PROFILES): cpu, the 2-core default;
    gpu, the CUDA learner's (device cuda, 256 envs, batch 8,192) with MuJoCo on every core."""


VARIANTS = ("sb3", "fast", "fast2", "sigtanh")


def sigmoid_tanh():
    """An nn.Module computing tanh as 2 sigmoid(2x) - 1 (within 2e-7 of torch.tanh in float32)
    with tanh's own backward (1 - y^2, from the output). torch 2.15's CPU `tanh` kernel takes
    ~140 us on 1,024 x 64 floats here, its `sigmoid` ~15 (studies/profile_update.py's
    sigtanh variant measures what that is worth to a run)."""
    import torch

    class _Function(torch.autograd.Function):
        @staticmethod
        def forward(ctx, x):
            y = torch.sigmoid(x * 2).mul_(2).sub_(1)
            ctx.save_for_backward(y)
            return y

        @staticmethod
        def backward(ctx, grad):
            (y,) = ctx.saved_tensors
            return torch.ops.aten.tanh_backward(grad, y)

    class SigmoidTanh(torch.nn.Module):
        def forward(self, x):
            return _Function.apply(x)

    return SigmoidTanh()


def use_sigmoid_tanh(policy) -> None:
    """Swap every nn.Tanh of the policy's networks for sigmoid_tanh() (no parameters move)."""
    import torch

    for net in (policy.mlp_extractor.policy_net, policy.mlp_extractor.value_net):
        for i, layer in enumerate(net):
            if type(layer) is torch.nn.Tanh:
                net[i] = sigmoid_tanh()


class Timers:
    """Accumulated seconds per part, from wrappers around the functions SB3 calls: wall time,
    and CPU time of the whole process (steadier on a loaded machine, where wall time also
    counts the time other processes hold the cores)."""

    def __init__(self):
        self.wall = defaultdict(float)
        self.cpu = defaultdict(float)

    def wrap(self, owner, name: str, part: str) -> None:
        inner = getattr(owner, name)

        def timed(*a, **k):
            t, c = time.perf_counter(), time.process_time()
            try:
                return inner(*a, **k)
            finally:
                self.wall[part] += time.perf_counter() - t
                self.cpu[part] += time.process_time() - c

        setattr(owner, name, timed)


def build(variant: str, quick: bool, logs: Path, train_profile: str = "cpu"):
    import torch

    from panda_lead.errors import UserError
    from panda_lead.training import TrainConfig, make_vec_env
    from panda_lead.training.callbacks import make_logger
    from panda_lead.training.config import PROFILES
    from panda_lead.training.fast_ppo import build_ppo

    if train_profile not in PROFILES:
        raise UserError(f"--train-profile must be one of {', '.join(PROFILES)}; got {train_profile!r}")
    machine = dict(PROFILES[train_profile])
    if train_profile != "cpu":
        machine["n_workers"] = os.cpu_count() or 1
    config = TrainConfig(**{**machine, "n_steps": 16 if quick else machine.get(
        "n_steps", TrainConfig.n_steps)}, seed=0)
    torch.set_num_threads(config.torch_threads)
    vec = make_vec_env(config.env, config.n_envs, config.seed, config.vec_env, config.n_workers)
    model = build_ppo(config, vec, fast=variant != "sb3",
                      update_threads=2 if variant == "fast2" else None)
    if variant == "sigtanh":
        use_sigmoid_tanh(model.policy)
    model.set_logger(make_logger(logs / variant))  # TensorBoard and CSV, as train.py logs
    model.learn(config.n_steps * config.n_envs)  # warm-up iteration
    return model, vec, config.n_steps * config.n_envs


def profile(model, per_iter: int, iterations: int) -> tuple[dict[str, float], dict[str, float]]:
    """Microseconds per sample of each part over ``iterations`` PPO iterations: (CPU, wall)."""
    import torch

    t = Timers()
    saved = (torch.Tensor.backward, torch.nn.utils.clip_grad_norm_)
    t.wrap(torch.Tensor, "backward", "update: backward")
    t.wrap(torch.nn.utils, "clip_grad_norm_", "update: clip grad norm")
    opt = model.policy.optimizer
    t.wrap(opt, "step", "update: optimiser (Adam, zero_grad)")
    t.wrap(opt, "zero_grad", "update: optimiser (Adam, zero_grad)")
    t.wrap(model.env, "step_wait", "env step (IK, physics, reward)")
    t.wrap(model.policy, "forward", "policy forward (collection)")
    fwd = "_evaluate_actions" if hasattr(model, "_evaluate_actions") else None
    t.wrap(model, fwd, "update: forward") if fwd else t.wrap(model.policy, "evaluate_actions",
                                                                "update: forward")
    t.wrap(model, "collect_rollouts", "collection")
    t.wrap(model, "train", "update")
    try:
        start, cstart = time.perf_counter(), time.process_time()
        model.learn(per_iter * iterations, reset_num_timesteps=False)
        totals = {"wall": time.perf_counter() - start, "cpu": time.process_time() - cstart}
    finally:
        torch.Tensor.backward, torch.nn.utils.clip_grad_norm_ = saved
        for obj, names in ((opt, ("step", "zero_grad")), (model.env, ("step_wait",)),
                           (model.policy, ("forward", "evaluate_actions")),
                           (model, ("_evaluate_actions", "collect_rollouts", "train"))):
            for n in names:
                obj.__dict__.pop(n, None)
    samples = per_iter * iterations
    result = []
    for clock, s in (("cpu", t.cpu), ("wall", t.wall)):
        total = totals[clock]
        parts = {
            PARTS[0]: s[PARTS[0]], PARTS[1]: s[PARTS[1]],
            PARTS[2]: s["collection"] - s[PARTS[0]] - s[PARTS[1]],
            PARTS[3]: s[PARTS[3]], PARTS[4]: s[PARTS[4]], PARTS[5]: s[PARTS[5]],
            PARTS[6]: s[PARTS[6]],
            PARTS[7]: s["update"] - sum(s[p] for p in PARTS[3:7]),
            PARTS[8]: total - s["collection"] - s["update"],
            "update (all)": s["update"], "total": total,
        }
        result.append({k: v / samples * 1e6 for k, v in parts.items()})
    return result[0], result[1]


def update_only(args: Args) -> None:
    """One model, one collected rollout; each variant's train() timed in turn on it."""
    import torch
    from stable_baselines3 import PPO

    from panda_lead.training.fast_ppo import FastPPO

    model, vec, _ = build("fast", args.quick, Path(tempfile.mkdtemp(prefix="profile_update_")),
                         args.train_profile)
    group = model.policy.optimizer.param_groups[0]

    def sb3():
        group["foreach"] = None  # SB3's Adam as it comes
        PPO.train(model)

    def fast(threads=1):
        group["foreach"] = True
        torch.set_num_threads(threads)
        try:
            FastPPO.train(model)
        finally:
            torch.set_num_threads(1)
    def sigtanh():
        nets = (model.policy.mlp_extractor.policy_net, model.policy.mlp_extractor.value_net)
        tanhs = [(net, i, layer) for net in nets for i, layer in enumerate(net)
                 if type(layer) is torch.nn.Tanh]
        use_sigmoid_tanh(model.policy)
        try:
            fast()
        finally:
            for net, i, layer in tanhs:
                net[i] = layer
    trains = {"sb3": sb3, "fast": fast, "fast2": lambda: fast(2), "sigtanh": sigtanh}
    wall = {v: [] for v in args.variants}
    cpu = {v: [] for v in args.variants}
    for r in range(args.update_only):
        for v in (args.variants if r % 2 == 0 else args.variants[::-1]):
            t, c = time.perf_counter(), time.process_time()
            trains[v]()
            wall[v].append((time.perf_counter() - t) * 1e3)
            cpu[v].append((time.process_time() - c) * 1e3)
    vec.close()
    base = args.variants[0]
    print(f"\n`uv run studies/profile_update.py {' '.join(sys.argv[1:])}` on "
          f"{os.cpu_count()} cores ({cpu_model_name()}), {time.strftime('%Y-%m-%d')}; one update "
          f"(n_epochs x minibatches), medians of {args.update_only} interleaved rounds\n")
    print("| variant | wall ms | CPU ms | wall / " + base + " (median of paired ratios) |")
    print("|---|---|---|---|")
    for v in args.variants:
        ratio = statistics.median(a / b for a, b in zip(wall[v], wall[base], strict=True))
        print(f"| {v} | {statistics.median(wall[v]):.0f} | {statistics.median(cpu[v]):.0f} "
              f"| {ratio:.2f} |")


def activations(args: Args) -> None:
    """Why tanh leads the update's profile: its kernel against the ops around it."""
    import numpy as np
    import torch

    torch.set_num_threads(1)
    x, w = torch.randn(1024, 64), torch.randn(64, 64)
    ours = sigmoid_tanh()
    with torch.no_grad():
        ops = {"torch.tanh": lambda: torch.tanh(x), "torch.sigmoid": lambda: torch.sigmoid(x),
               "sigtanh (2 sigmoid(2x) - 1)": lambda: ours(x),
               "numpy tanh": lambda: np.tanh(x.numpy()), "matmul 1,024 x 64 by 64 x 64": lambda: x @ w}
        print(f"`uv run studies/profile_update.py {' '.join(sys.argv[1:])}` on {cpu_model_name()}, "
              f"{time.strftime('%Y-%m-%d')}, torch {torch.__version__}, kernels "
              f"{torch.backends.cpu.get_cpu_capability()}; us per call on 1,024 x 64 float32, "
              "median of 5 rounds\n")
        print("| op | us per call |\n|---|---|")
        for name, op in ops.items():
            for _ in range(50):
                op()
            rounds = []
            for _ in range(5):
                t = time.perf_counter()
                for _ in range(args.activations):
                    op()
                rounds.append((time.perf_counter() - t) / args.activations * 1e6)
            print(f"| {name} | {statistics.median(rounds):.1f} |")


def cpu_model_name() -> str:
    from bench import cpu_model

    return cpu_model()


def cprofile(args: Args) -> None:
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    with tempfile.TemporaryDirectory() as tmp:
        model, vec, per_iter = build(args.variants[0], args.quick, Path(tmp), args.train_profile)
        try:
            profiler.enable()
            model.learn(per_iter * args.cprofile, reset_num_timesteps=False)
        finally:
            profiler.disable()
            vec.close()
    stats = pstats.Stats(profiler)
    samples = per_iter * args.cprofile
    print(f"{args.variants[0]}, profile {args.train_profile}, {args.cprofile} iterations "
          f"({samples:,} samples) on {os.cpu_count()} cores ({cpu_model_name()}), cProfile on: "
          f"{stats.total_tt / samples * 1e6:.0f} us wall per sample (cProfile adds its own)")
    cum = {}
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():
        key = f"{Path(file).name}:{name}"
        cum[key] = max(cum.get(key, 0.0), ct)
    rollout = "~:<built-in method mujoco._batch.rollout>"
    for label, key in (("MuJoCo's batched rollout (physics)", rollout),
                       ("the env step (task.py)", "task.py:step"),
                       ("SB3's collection, all", "on_policy_algorithm.py:collect_rollouts"),
                       ("the policy's forward (collection)", "fast_ppo.py:forward"),
                       ("the policy's forward (SB3's)", "policies.py:forward"),
                       ("the update", "fast_ppo.py:train")):
        if key in cum:
            print(f"  {label}: {cum[key] / samples * 1e6:.1f} us per sample")
    stats.sort_stats("tottime").print_stats(15)
    # On the device (Python 3.12) the env step's label read 0.0 us although the IK and MuJoCo
    # it calls were timed (cause not found): the cumulative listing shows what a label misses.
    stats.sort_stats("cumulative").print_stats(25)


def main() -> None:
    args = parse_cli(Args, description=__doc__)
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        raise UserError(f"unknown variant {unknown[0]!r}; choose from {', '.join(VARIANTS)}")
    if args.activations:
        return activations(args)
    if args.update_only:
        return update_only(args)
    if args.cprofile:
        return cprofile(args)
    from bench import bench_physics, cpu_model

    cores = os.cpu_count() or 1
    logs = Path(tempfile.mkdtemp(prefix="profile_update_"))
    models = {v: build(v, args.quick, logs, args.train_profile) for v in args.variants}
    runs: dict[str, list[dict]] = {v: [] for v in args.variants}  # CPU us per sample
    walls: dict[str, list[dict]] = {v: [] for v in args.variants}
    physics = []
    for r in range(args.pairs):
        order = args.variants if r % 2 == 0 else args.variants[::-1]
        physics.append(bench_physics(400 if args.quick else 2000, 3))
        for v in order:
            model, _, per_iter = models[v]
            cpu, wall = profile(model, per_iter, 1 if args.quick else args.iterations)
            runs[v].append(cpu)
            walls[v].append(wall)
            print(f"round {r + 1} {v}: {cpu['total']:.1f} us CPU, {wall['total']:.1f} us wall "
                  f"per sample ({1e6 / wall['total']:,.0f} samples/s)", flush=True)
    for _model, vec, _ in models.values():
        vec.close()
    shutil.rmtree(logs, ignore_errors=True)
    phys = statistics.median(physics)
    base = args.variants[0]

    def median_ratio(rs, v, k):
        return statistics.median(a[k] / b[k] for a, b in zip(rs[v], rs[base], strict=True))

    print(f"\n`uv run studies/profile_update.py {' '.join(sys.argv[1:])}` on {cores} cores "
          f"({cpu_model()}), {time.strftime('%Y-%m-%d')}, Python {platform.python_version()}; "
          f"medians of {args.pairs} rounds, process CPU us per collected sample "
          f"(wall: the last rows)\n")
    print(f"| part | {' | '.join(args.variants)} |"
          + "".join(f" {v} / {base} (median of paired ratios) |" for v in args.variants[1:]))
    print("|---|" + "---|" * (2 * len(args.variants) - 1))
    for label, rs, keys in (("", runs, [*PARTS, "update (all)", "total"]),
                            ("wall: ", walls, ["update (all)", "total"])):
        for k in keys:
            cells = " | ".join(f"{statistics.median(r[k] for r in rs[v]):.1f}"
                               for v in args.variants)
            ratios = "".join(f" {median_ratio(rs, v, k):.2f} |"
                             if min(b[k] for b in rs[base]) > 0.05 else " - |"
                             for v in args.variants[1:])
            print(f"| {label}{k} | {cells} |{ratios}")
    rates = {v: 1e6 / statistics.median(r["total"] for r in walls[v]) for v in args.variants}
    print(f"| wall samples/s | {' | '.join(f'{rates[v]:,.0f}' for v in args.variants)} |"
          + "".join(f" {1 / median_ratio(walls, v, 'total'):.2f}x |" for v in args.variants[1:]))
    limit = cores / phys * 1e6
    print(f"\nphysics-bound limit: raw physics {phys:.1f} us per env step (median of "
          f"{len(physics)}, one thread) -> {limit:,.0f} samples/s on {cores} cores; "
          + ", ".join(f"{v} at {rates[v] / limit:.0%} of it" for v in args.variants))

if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(main)()
