"""The command line shared by eval.py and ikpd.py: one episode to watch or record, or a seed
range to write rollout files. Both scripts run every controller through the same code path.

Env settings are typed flags (``--env.obs-noise target_vel 0.05``, ``--env.max-lead 0.1``);
only the ones given apply, over the model's sidecar config (or the env's defaults)."""

from __future__ import annotations

import dataclasses
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

from ..config import EnvConfig, config_docs
from ..errors import UserError, did_you_mean, exit_on_user_error


def _overrides_class(cls=EnvConfig, name: str = "EnvOverrides"):
    """``cls`` with every field optional (None: not given): what --env.X sets. A nested config
    (ik) becomes a nested overrides class, so --env.ik.damping sets that knob alone."""
    hints = typing.get_type_hints(cls)
    docs = config_docs(cls)
    fields = []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            sub = _overrides_class(kind, f"{kind.__name__}Overrides")
            fields.append((f.name, sub, field(default_factory=sub)))
            continue
        fields.append((f.name, Annotated[kind | None, tyro.conf.arg(
            help=docs[f.name], help_behavior_hint="(default: the model's, else the env's)")],
            field(default=None)))
    return dataclasses.make_dataclass(name, fields, frozen=True)


def given(overrides) -> dict:
    """The flags given, as EnvConfig.merged takes them ({"ik": {"damping": 0.1}, ...})."""
    out = {}
    for f in dataclasses.fields(overrides):
        v = getattr(overrides, f.name)
        if dataclasses.is_dataclass(v):
            v = given(v) or None
        if v is not None:
            out[f.name] = v
    return out


EnvOverrides = _overrides_class()


@dataclass
class Args:
    seed: int | None = None
    """Trajectory seed of a single episode (default: a random one)."""
    seeds: str | None = None
    """Seed range such as 0-99 or 0-4,10 (at most 100,000 seeds): write one rollout file per
    seed under --prefix."""
    prefix: str = "eval"
    """Rollout set name (a plain name): files go to <rollouts-dir>/<prefix>/seed_NNNN.npz."""
    controller: Literal["policy", "classical", "analytic"] = "policy"
    """Which lead: a trained policy, none (classical), or v*tau + a*tau^2/2 (analytic)."""
    model: Path | None = None
    """Policy zip with its sidecar (default: archive/indep_v5.zip, the headline model)."""
    tau: float | None = None
    """Look-ahead of the analytic lead in seconds (default: the tuned value)."""
    shape: str | None = None
    """Force the trajectory shape (circle, fig8, fly) instead of drawing it from the seed."""
    duration: float = 5.0
    """Episode length in seconds."""
    video: Path | None = None
    """Render the single episode offscreen to this MP4 instead of opening the viewer."""
    compare: tuple[Literal["classical", "analytic", "policy"], ...] | None = None
    """With --video: two controllers side by side on the same seed, e.g. --compare classical
    analytic. --compare alone: classical beside --controller (the policy if that is classical)."""
    stochastic: bool = False
    """Sample policy actions instead of taking the mean."""
    env: EnvOverrides = field(default_factory=EnvOverrides)  # type: ignore[valid-type]
    """Env settings applied over the model's (only the flags given)."""
    rollouts_dir: Path = Path("rollouts")
    """Root folder of rollout sets."""
    force: bool = False
    """Write into a --prefix that holds another controller's or model's rollouts (those files
    are deleted first, so the set never mixes two)."""


PREFIX_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def _validate(args: Args):
    import math

    from .. import trajectory
    from ..seeds import parse_seed_range

    seeds = parse_seed_range(args.seeds) if args.seeds is not None else None
    if not PREFIX_RE.fullmatch(args.prefix):
        raise UserError(f"--prefix must be a plain name (letters, digits, _ . + -, not starting "
                        f"with a dot; no / or ..), got {args.prefix!r}")
    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.shape is not None and args.shape not in trajectory.SHAPES:
        raise UserError(f"unknown shape {args.shape!r}" + did_you_mean(args.shape, trajectory.SHAPES))
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise UserError(f"--duration must be a positive number, got {args.duration}")
    if args.tau is not None and not (math.isfinite(args.tau) and args.tau >= 0):
        raise UserError(f"--tau must be a finite number >= 0, got {args.tau}")
    if args.compare is not None and args.video is None:
        raise UserError("--compare renders a video: add --video out.mp4")
    if args.compare and len(args.compare) != 2:
        raise UserError(f"--compare takes two controllers (or none), got {' '.join(args.compare)}")
    overrides = given(args.env)
    EnvConfig().merged(overrides)  # a bad value is one clear line before any work
    return seeds, overrides


def _build(args: Args, overrides: dict):
    """-> (env, act_fn, meta) for the chosen controller; a policy's env comes from its sidecar."""
    from .. import controllers
    from ..core import control_dt
    from ..env import PandaLeadEnv
    from ..models import DEFAULT_MODEL, archived, load_policy

    steps = int(round(args.duration / control_dt()))
    meta = {"controller": args.controller, "model": None}
    env_kwargs: dict = {}
    act = controllers.classical
    model = None
    if args.controller == "policy" or args.compare:
        path = args.model or archived(DEFAULT_MODEL)
        model, env_kwargs, side = load_policy(path)
        meta["model"] = str(path)
        meta["model_sha256"] = side["model_sha256"]
    if args.controller == "policy":
        act = controllers.make_policy(model, deterministic=not args.stochastic)
    elif args.controller == "analytic":
        tau = controllers.DEFAULT_TAU if args.tau is None else args.tau
        act = controllers.make_analytic(tau)
        meta["tau"] = tau
    if args.controller != "policy":
        meta["model"] = None
        meta.pop("model_sha256", None)
    config = EnvConfig.from_dict(env_kwargs).merged({**overrides, "episode_steps": steps})
    render = "rgb_array" if args.video else None
    env = PandaLeadEnv(config, render_mode=render)
    return env, act, meta, model


IDENTITY_KEYS = ("controller", "model_sha256", "tau")


def _claim_prefix(folder: Path, meta: dict, env_config: dict, force: bool):
    """Lock a rollout folder for this run (flock: a second run on it is refused, so two runs
    never mix) and check that it holds only rollouts of this controller, model and env; with
    ``force``, the others are deleted. Returns the open lock file (keep it until done)."""
    import fcntl

    from ..rollout import read_meta

    folder.mkdir(parents=True, exist_ok=True)
    lock = open(folder / ".lock", "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise UserError(f"{folder}: another run is writing rollouts there now; wait for it or "
                        "choose another --prefix") from None
    mine = {k: meta.get(k) for k in IDENTITY_KEYS}
    others = []
    for f in sorted(folder.glob("seed_*.npz")):
        try:
            m = read_meta(f)
            theirs = {k: m.get(k) for k in IDENTITY_KEYS}
            same_env = {**m.get("env", {}), "episode_steps": None} == {**env_config,
                                                                      "episode_steps": None}
        except UserError:
            theirs, same_env = {"controller": "unreadable file"}, False
        if theirs != mine or not same_env:
            others.append((f, theirs))
    if others and not force:
        f, theirs = others[0]
        what = theirs.get("controller") + (f" (model {theirs['model_sha256'][:12]})"
                                           if theirs.get("model_sha256") else "")
        lock.close()
        raise UserError(f"{folder} holds {len(others)} rollouts of another controller, model or "
                        f"env ({f.name}: {what}); choose another --prefix, or add --force to "
                        "delete them and write this set")
    for f, _ in others:
        f.unlink()
    return lock


def write_rollouts(args: Args, seeds: list[int], overrides: dict) -> None:
    from ..rollout import record_many, rollout_path, save

    env, act, meta, _ = _build(args, overrides)
    folder = args.rollouts_dir / args.prefix
    lock = _claim_prefix(folder, meta, env.cfg.to_dict(), args.force)
    try:
        shapes = [args.shape] * len(seeds)
        for r in record_many(env.cfg, act, seeds, shapes, meta):
            seed = r.seed
            save(r, rollout_path(args.prefix, seed, args.rollouts_dir))
            note = f"  FAILED: {r.meta['failure']}" if r.meta.get("failure") else ""
            print(f"seed {seed:4d} {r.shape:6s} mean error {100 * r.error.mean():6.2f} cm{note}")
    finally:
        lock.close()
    print(f"wrote {len(seeds)} rollouts to {folder}/")


def compare_pair(args: Args) -> tuple[str, str] | None:
    """The two controllers of --compare, left then right: as named, or classical beside
    --controller (the policy when --controller is classical, as --compare always did)."""
    if args.compare is None:
        return None
    if args.compare:
        return tuple(args.compare)
    return "classical", args.controller if args.controller != "classical" else "policy"


def write_video(args: Args, seed: int, overrides: dict) -> None:
    from .. import video
    from ..rollout import record

    names = compare_pair(args) or (args.controller,)
    # Each controller is built as if run alone, so its meta (and the label drawn from it) says
    # what really drove it; every side then runs on one env, the policy's (from its sidecar)
    # when one side is the policy, so both track the same task and the model loads once.
    built = {n: _build(dataclasses.replace(args, controller=n, compare=None), overrides)
             for n in dict.fromkeys(names)}
    env = built["policy"][0] if "policy" in built else built[names[0]][0]
    rollouts = [record(env, built[n][1], seed, args.shape, built[n][2]) for n in names]
    for other_env, *_ in built.values():
        other_env.close()
    out = Path(args.video)
    video.write(out, rollouts, env.core.model)  # a failed write is a UserError, old file kept
    pairs = zip(names, rollouts, strict=True)
    summary = ", ".join(f"{n} {100 * r.error.mean():.2f} cm" for n, r in pairs)
    print(f"seed {seed} ({rollouts[0].shape}): mean error {summary}; wrote {out}")


def watch(args: Args, seed: int, overrides: dict) -> None:
    from ..display import has_display

    if not has_display():
        raise UserError("no display for the viewer: record instead with --video out.mp4, or "
                        "write rollout files with --seeds 0-9 --prefix NAME")
    import time

    import mujoco.viewer

    env, act, _, _ = _build(args, overrides)
    obs, _ = env.reset(seed=seed, options={"traj_seed": seed, **(
        {"shape": args.shape} if args.shape else {})})
    data = env.core.get_data(0)
    with mujoco.viewer.launch_passive(env.core.model, data) as viewer:
        done = False
        while viewer.is_running() and not done:
            start = time.perf_counter()
            obs, _, term, trunc, info = env.step(act(obs[None], env.task)[0])
            done = term or trunc
            env.core.get_data(0, data)
            viewer.sync()
            time.sleep(max(0.0, env.dt - (time.perf_counter() - start)))


def run_controller_cli(default_controller: str, default_prefix: str, argv, prog: str,
                       description: str | None = None) -> None:
    from . import models as model_commands

    if model_commands.wants(argv):  # --restore-sidecar (and --adopt): the model-file commands
        model_commands.main(list(argv), prog)
        return
    defaults = Args(controller=default_controller, prefix=default_prefix)
    args = tyro.cli(Args, args=argv, default=defaults, prog=prog, description=description)
    _run(args)


@exit_on_user_error  # UserError, ModelError, bad seeds/shapes: one line, exit 2; bugs keep traces
def _run(args: Args) -> None:
    seeds, overrides = _validate(args)
    if seeds is not None:
        write_rollouts(args, seeds, overrides)
    else:
        seed = args.seed if args.seed is not None else int(np.random.default_rng().integers(
            0, 2**31 - 1))
        if args.video:
            write_video(args, seed, overrides)
        else:
            watch(args, seed, overrides)
