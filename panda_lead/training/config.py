"""The training config: `TrainConfig` (everything that decides what a run learns), `TrainArgs`
(train.py's command line: the config plus where the run goes), and the rules for resuming.

config.json and every sidecar store a TrainConfig whole; presets (presets.py) are values of it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

from ..config import MAX_EPISODE_STEPS, EnvConfig
from ..errors import UserError, check_plain_name

MAX_TIMESTEPS = 10**12  # a typo's bound, not a budget: years of training on any machine here
MAX_THREADS = 1024


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides what a training run learns. config.json and every sidecar store
    it whole; presets are values of it."""

    env: EnvConfig = EnvConfig()
    """The env's settings (see env.EnvConfig), e.g. --env.max-lead 0.1."""
    timesteps: int = 5_000_000
    """Total environment steps (PPO collects whole rollouts of n_steps x n_envs, so a run ends
    at the next multiple; train.py says so)."""
    n_envs: int = 32
    """Parallel environments (reference: 8)."""
    n_steps: int = 128
    """Steps per environment per PPO rollout (reference: 1024)."""
    batch_size: int = 1024
    """PPO minibatch size (reference: 64)."""
    n_epochs: int = 10
    """PPO epochs per rollout."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    learning_rate: float = 1e-3
    """Adam learning rate (reference: 3e-4)."""
    lr_schedule: Literal["constant", "linear"] = "constant"
    """constant: the learning rate throughout; linear: from --learning-rate down to 0 at
    --timesteps (SB3's progress_remaining), and 0 for the rollout that crosses it."""
    clip_range: float = 0.2
    """PPO clipping parameter."""
    ent_coef: float = 0.0
    """Entropy bonus coefficient."""
    target_kl: float | None = None
    """Stop an update's epochs early once the approximate KL divergence from the rollout's
    policy passes 1.5x this (SB3's guard; None: never). The IK-free policy at 1e-3 came apart
    with its KL per update rising to 0.2-0.3 (docs/questions.md 7)."""
    net_arch: tuple[int, ...] = (64, 64)
    """Hidden layer sizes of the policy and value MLPs (tanh)."""
    log_std_init: float = -1.0
    """Initial log standard deviation of the Gaussian policy (reference and SB3: 0, std 1)."""
    seed: int = 42
    """Seeds Python, numpy, torch and the environments' streams."""
    device: str = "cpu"
    """Torch device (a 64x64 MLP runs fastest on the CPU)."""
    torch_threads: int = 1
    """Torch threads of the training process. One: while the policy acts, the env workers need
    every other core, and idle torch threads spin on them (2 threads on 2 cores: 3-6x slower)."""
    vec_env: Literal["batched", "subproc", "dummy"] = "batched"
    """batched: all envs in one mujoco.batch.Batch in this process (sb3_vecenv.py); subproc: SB3
    SubprocVecEnv, a process per env (the reference configuration); dummy: a loop of single
    envs in this process."""
    n_workers: int = 0
    """MuJoCo threads stepping the batched envs (0: one per CPU core)."""
    fast_update: bool = True
    """Run PPO's update through training/fast_ppo.py's FastPPO: SB3's update, bit-identical
    (tests/test_fast_ppo.py), with fewer Python-level operations per minibatch; off: SB3's PPO
    as it comes (docs/performance.md, "Profile of one training iteration")."""
    caps_temporal: float = 0.0
    """CAPS temporal smoothness weight (issue 36; needs the fast update): PPO's loss plus this
    x the mean squared change of the policy's mean action between consecutive observations of
    an episode (training/fast_ppo.py). 0: off, PPO as SB3 runs it."""
    caps_spatial: float = 0.0
    """CAPS spatial smoothness weight: PPO's loss plus this x the mean squared change of the
    mean action under Gaussian noise of --caps-sigma on the observation. 0: off."""
    caps_curvature: float = 0.0
    """Curvature smoothness weight (issue 36; needs the fast update): PPO's loss plus this x
    the mean squared second difference of the policy's mean action over three consecutive
    observations of an episode: the lead's acceleration, where a first difference (CAPS's
    temporal term) also charges the lead's slow changes. 0: off."""
    caps_curvature_delayed: float | None = None
    """The curvature weight in the episodes with latency (any of the installation feature's
    three delays non-zero; the observation must hold ``installation``), caps_curvature in the
    rest: the calm a delayed loop needs without charging the precise one. None: caps_curvature
    everywhere."""
    caps_sigma: float = 0.05
    """Standard deviation of the spatial term's observation noise, in observation units (each
    feature divided by its config.OBS_SCALE: 0.05 is 5 cm on a position, 2.5 mm on the tip
    error, 0.125 m/s on a velocity)."""
    use_sde: bool = False
    """Explore with SB3's generalized state-dependent exploration (gSDE) instead of a fresh
    Gaussian draw per step: the noise is the policy's last hidden layer times a random matrix,
    drawn every --sde-sample-freq steps, so it varies as smoothly as the state does. White
    per-step noise shakes the 100 Hz joint goals far over the Panda's acceleration limits
    whatever the policy's mean does (docs/deploy.md, "Where the acceptance gap lies");
    --log-std-init then scales the matrix's entries (the action's std is about their std x
    the norm of the hidden layer)."""
    sde_sample_freq: int = -1
    """With --use-sde: draw a new noise matrix every this many steps (-1: once per rollout)."""
    eval_freq: int = 50_000
    """Evaluate on the fixed evaluation set every this many total steps (0: never)."""
    eval_steps: int = 500
    """Steps per evaluation episode (500 = 5 s, as the test rollouts)."""
    checkpoint_freq: int = 500_000
    """Save a checkpoint every this many total steps."""
    stop_below_cm: float | None = None
    """Stop as soon as the evaluation-set mean error drops below this (time-to-quality runs)."""
    curriculum_steps: int = 500_000
    """Speed curriculum: over this many steps the training targets' peak-speed cap rises
    linearly from --curriculum-start-speed to none (0: no curriculum). On by default: it
    reaches the time-to-quality threshold in half the steps (docs/performance.md) and ends as
    well (docs/questions.md 5); the presets, the reference ladder, run without it."""
    curriculum_start_speed: float = 0.8
    """Peak-speed cap (m/s) of the training targets at step 0 of a curriculum."""
    init_from: str | None = None
    """Start from a trained model's weights instead of random ones (training/warm_start.py):
    inputs this run observes and the model did not start at zero weight, so the first policy's
    mean is the model's (its exploration starts at --log-std-init). ``{seed}`` in the path is
    replaced by --seed (one starting model per training seed, e.g.
    archive/seeds/v5_err_decay_kept_s{seed}.zip). None: a fresh network."""
    init_keep_std: bool = False
    """With --init-from: explore at the starting model's trained std, not --log-std-init (a
    fine-tune in the model's own world; a world that changed needs the wider restart,
    training/warm_start.py says why)."""
    preset: str | None = None
    """Start from a preset (see the list above); every flag given overrides it."""

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        if isinstance(self.env, dict):
            set_("env", EnvConfig.from_dict(self.env))
        if not isinstance(self.env, EnvConfig):
            raise UserError(f"env must be an EnvConfig, got {type(self.env).__name__}")
        set_("net_arch", tuple(self.net_arch))
        for name, low in (("timesteps", 1), ("n_envs", 1), ("n_steps", 1), ("batch_size", 2),
                          ("n_epochs", 1), ("torch_threads", 1), ("n_workers", 0),
                          ("eval_freq", 0), ("eval_steps", 1), ("checkpoint_freq", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise UserError(f"--{flag(name)} must be an integer >= {low}, got {v!r}")
        # Upper bounds, so that a typo is one line before a run folder is made: numpy seeds
        # take 0..2^32-1, thread pools beyond a thousand fail inside MuJoCo or torch, an
        # evaluation episode is at most MAX_EPISODE_STEPS, and 10^12 steps is years of training.
        for name, high in (("seed", 2**32 - 1), ("timesteps", MAX_TIMESTEPS),
                           ("torch_threads", MAX_THREADS), ("n_workers", MAX_THREADS),
                           ("eval_steps", MAX_EPISODE_STEPS)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= high:
                raise UserError(f"--{flag(name)} must be an integer in 0..{high:,}, got {v!r}")
        if isinstance(self.sde_sample_freq, bool) or not isinstance(self.sde_sample_freq, int) \
                or self.sde_sample_freq < -1:
            raise UserError(f"--sde-sample-freq must be -1 or a step count >= 0, got "
                            f"{self.sde_sample_freq!r}")
        if self.n_steps * self.n_envs < 2:
            raise UserError("a PPO rollout needs at least 2 steps: raise --n-steps or --n-envs")
        for name, lo, hi, lo_open in (("gamma", 0, 1, True), ("gae_lambda", 0, 1, False),
                                      # above 1, Adam's steps overflow (a traceback mid-run)
                                      ("learning_rate", 0, 1, True),
                                      ("clip_range", 0, math.inf, True),
                                      ("ent_coef", 0, math.inf, False),
                                      ("log_std_init", -math.inf, math.inf, False),
                                      ("caps_temporal", 0, math.inf, False),
                                      ("caps_spatial", 0, math.inf, False),
                                      ("caps_curvature", 0, math.inf, False),
                                      ("caps_curvature_delayed", 0, math.inf, False),
                                      ("caps_sigma", 0, math.inf, True)):
            v = getattr(self, name)
            if v is None and name == "caps_curvature_delayed":  # unset: caps_curvature's
                continue
            ok = isinstance(v, int | float) and math.isfinite(v) and v <= hi and (
                v > lo if lo_open else v >= lo)
            if not ok:
                rng = f"in ({lo}, {hi}]" if hi < math.inf else (">" if lo_open else ">=") + f" {lo}"
                raise UserError(f"--{flag(name)} must be a finite number {rng}, got {v!r}"
                                if math.isfinite(lo) else f"--{flag(name)} must be finite, got {v!r}")
            set_(name, float(v))
        if self.init_from is not None and (
                not isinstance(self.init_from, str) or not self.init_from.strip()
                or "{" in self.init_from.replace("{seed}", "")
                or "}" in self.init_from.replace("{seed}", "")):
            raise UserError(f"--init-from must be a model's path ({{seed}} the only "
                            f"placeholder), got {self.init_from!r}")
        if not isinstance(self.init_keep_std, bool):
            raise UserError(f"init_keep_std must be true or false, got {self.init_keep_std!r}")
        if self.init_keep_std and self.init_from is None:
            raise UserError("--init-keep-std keeps a starting model's exploration: it needs "
                            "--init-from")
        if not isinstance(self.fast_update, bool):
            raise UserError(f"fast_update must be true or false, got {self.fast_update!r}")
        if self.caps_curvature_delayed is not None:
            if "installation" not in self.env.obs_features:
                raise UserError("--caps-curvature-delayed needs the installation feature in "
                                "the observation (--env.obs-features ... installation): it "
                                "tells the update which episodes have latency")
        if (self.caps_temporal or self.caps_spatial or self.caps_curvature
                or self.caps_curvature_delayed) and not self.fast_update:
            raise UserError("--caps-temporal, --caps-spatial and --caps-curvature need the fast "
                            "update (FastPPO): drop --no-fast-update")
        if "plan_weight" in self.env.obs_features and not self.fast_update:
            raise UserError("the plan_weight feature's policy loss (the steps the planner's hand "
                            "holds left out) needs the fast update (FastPPO): drop "
                            "--no-fast-update")
        if self.lr_schedule not in ("constant", "linear"):
            raise UserError(f"--lr-schedule must be constant or linear, got {self.lr_schedule!r}")
        if not self.net_arch or any(isinstance(n, bool) or not isinstance(n, int) or n < 1
                                    for n in self.net_arch):
            raise UserError(f"--net-arch must be positive layer sizes, got {self.net_arch!r}")
        if self.stop_below_cm is not None and not (math.isfinite(self.stop_below_cm)
                                                   and self.stop_below_cm > 0):
            raise UserError(f"--stop-below-cm must be > 0, got {self.stop_below_cm!r}")
        if self.target_kl is not None and not (isinstance(self.target_kl, int | float)
                                               and math.isfinite(self.target_kl)
                                               and self.target_kl > 0):
            raise UserError(f"--target-kl must be a finite number > 0, got {self.target_kl!r}")
        if isinstance(self.curriculum_steps, bool) or not isinstance(self.curriculum_steps, int) \
                or self.curriculum_steps < 0:
            raise UserError(f"--curriculum-steps must be an integer >= 0, got {self.curriculum_steps!r}")
        if not (math.isfinite(self.curriculum_start_speed) and self.curriculum_start_speed > 0.25):
            raise UserError("--curriculum-start-speed must be above 0.25 m/s, got "
                            f"{self.curriculum_start_speed!r}")

    def to_dict(self) -> dict:
        """JSON-friendly, whole: what config.json and sidecars hold."""
        d = asdict(self)
        d["env"] = self.env.to_dict()
        d["net_arch"] = list(self.net_arch)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        """From config.json; also reads the format before TrainConfig (ppo sub-dict, env
        kwargs plus env_resolved)."""
        d = dict(d)
        if "ppo" in d:  # the older layout
            d.update(d.pop("ppo"))
            d["env"] = d.pop("env_resolved", None) or d.get("env", {})
        # Configs written before the curriculum existed trained without one.
        d.setdefault("curriculum_steps", 0)
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


def flag(name: str) -> str:
    return name.replace("_", "-")


@dataclass(frozen=True)
class TrainArgs(TrainConfig):
    """train.py's command line: the training config plus where the run goes and what happens
    around it."""

    reference_hparams: bool = False
    """Start from the reference work's PPO settings (8 SubprocVecEnv envs, n_steps 1024,
    batch 64, lr 3e-4, log_std_init 0); flags given still override them."""
    profile: Literal["auto", "cpu", "gpu"] = "auto"
    """The machine's PPO collection and batch sizes (training/config.py PROFILES): cpu, the
    2-core defaults; gpu, a CUDA learner's (device cuda, more envs, larger minibatches); auto:
    gpu when --device cuda is given, else cpu. Flags given still override them."""
    runs_dir: Path = Path("runs")
    """Where run folders are created."""
    name: str | None = None
    """Run name prefix (default: the preset, else 'lead')."""
    resume: Path | None = None
    """Continue a run folder from its newest valid checkpoint (or interrupted model); only the
    run-time flags (--timesteps, --eval-freq, --checkpoint-freq, ...) may change."""
    archive: str | None = None
    """At the end, copy the best model to archive/NAME.zip with its sidecar, test metrics and a
    model card (archive/NAME.md)."""
    force: bool = False
    """Replace an existing archive/NAME.zip."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self):
        super().__post_init__()
        for flag, value in (("--name", self.name), ("--archive", self.archive)):
            if value is not None:
                check_plain_name(value, flag)

    def config(self) -> TrainConfig:
        return TrainConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(TrainConfig)})


# The reference work's configuration (what `--reference-hparams` starts from).
REFERENCE_HPARAMS = dict(n_envs=8, vec_env="subproc", n_steps=1024, batch_size=64, n_epochs=10,
                         learning_rate=3e-4, log_std_init=0.0, curriculum_steps=0)


# Machine profiles: PPO's collection and batch sizes for the machine that trains (what
# `--profile` starts from; every flag given still overrides them). cpu: the defaults above,
# chosen on 2 cores (docs/performance.md, "Time to quality"). gpu: the fastest measured on a
# 16-core + H100 machine, 3.2x the cpu profile's samples/s there with 8x fewer gradient steps
# per sample; the same time to a 2.5 cm evaluation error, and after 5M steps the same test error
# (5 seeds each, paired by seed: +0.017 cm [-0.071, +0.106]; docs/performance.md, "16 cores and
# a GPU"). `--device cuda` picks it unless `--profile cpu` is given.
PROFILES: dict[str, dict] = {
    "cpu": {},
    "gpu": dict(device="cuda", n_envs=256, n_steps=128, batch_size=8192),
}


# Run-time settings --resume may change; the rest must stay what the run was trained with.
# torch_threads is not among them: the thread count changes torch's float reductions, and so the
# trained weights. n_workers (MuJoCo's threads) and fast_update (a bit-identical update) do not
# change any result.
RESUME_MAY_CHANGE = ("timesteps", "eval_freq", "eval_steps", "checkpoint_freq", "stop_below_cm",
                     "device", "n_workers", "fast_update")


def read_run_config(run_dir: Path) -> TrainConfig:
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise UserError(f"--resume {run_dir}: not a run folder (no config.json)")
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise TypeError(f"a JSON object is needed, got {type(data).__name__}")
        return TrainConfig.from_dict(data)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, TypeError, ValueError,
            UserError) as exc:
        raise UserError(f"{path}: unreadable run config ({exc})") from None


def physical_memory() -> int:
    """Bytes of RAM on this machine."""
    import os

    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def memory_estimate(config: TrainConfig) -> int:
    """A lower bound on the bytes a run needs, from the sizes that scale: PPO's rollout buffer
    (float32: observations, actions, and six per-step scalars), the policy and value MLPs with
    Adam's two moments and the gradients, one MjData and the precomputed target path per arm.
    Enough to refuse a typo (a million envs, a 200,000-wide layer) before anything is created."""
    from ..config import OBS_FEATURES

    obs = sum(OBS_FEATURES[f] for f in config.env.obs_features) * config.env.obs_stack
    act = 7 if config.env.action != "lead" else 3
    buffer = config.n_envs * config.n_steps * (obs + 2 * act + 6) * 4
    layers = [obs, *config.net_arch]
    params = 2 * sum(a * b + b for a, b in zip(layers, layers[1:], strict=False))
    params += config.net_arch[-1] * (act + 1) + act
    net = params * 4 * 4  # weights, gradients, Adam's two moments
    per_arm = 60_000 + (config.env.episode_steps + 1) * 9 * 8 * 2  # MjData; path (+ eval)
    return buffer + net + config.n_envs * per_arm


def check_fits(config: TrainConfig) -> None:
    """UserError when a run cannot fit in this machine's memory (before any folder is made)."""
    need, have = memory_estimate(config), physical_memory()
    if need > 0.8 * have:
        raise UserError(f"this run needs at least {need / 2**30:.1f} GiB of memory (n_envs "
                        f"{config.n_envs}, n_steps {config.n_steps}, net_arch "
                        f"{list(config.net_arch)}, episode_steps {config.env.episode_steps}); "
                        f"this machine has {have / 2**30:.1f} GiB")
