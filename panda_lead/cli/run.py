"""The command line shared by eval.py and ikpd.py: one episode to watch or record, or a seed
range to write rollout files. Both scripts run every controller through the same code path.

Env settings are typed flags (``--env.obs-noise target_vel 0.05``, ``--env.max-lead 0.1``);
only the ones given apply, over the model's sidecar config (or the env's defaults)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from .. import harness
from ..config import EnvConfig
from ..errors import UserError, did_you_mean, exit_on_user_error, parse_cli
from ..ilc import ILCConfig
from .overrides import EnvOverrides, given


@dataclass
class Args:
    seed: int | None = None
    """Trajectory seed of a single episode (default: a random test seed, 0-999, never a
    training trajectory)."""
    seeds: str | None = None
    """Seed range such as 0-99 or 0-4,10 (at most 100,000 seeds): write one rollout file per
    seed under --prefix."""
    prefix: str = "eval"
    """Rollout set name (a plain name): files go to <rollouts-dir>/<prefix>/seed_NNNN.npz."""
    controller: Literal["policy", "classical", "analytic", "ilc", "future_target",
                        "feedforward", "feedforward_plan"] = "policy"
    """Which lead: a trained policy, none (classical), v*tau + a*tau^2/2 (analytic), the
    ILC ORACLE (replays each trajectory and learns its lead from the errors it saw: a ceiling,
    not a controller; started from the --model's lead by default, see --ilc), or a rival that
    knows the planned path: the IK aimed at the future target p(t + tau) (future_target), or
    joint goals that invert the simulated servos on the planned joint path (feedforward), or
    those goals followed open-loop wherever the arm can follow the whole plan, the feedforward
    elsewhere (feedforward_plan)."""
    model: Path | None = None
    """Policy zip with its sidecar (default: the headline model, models.DEFAULT_MODEL, in
    ./archive or the archive shipped with the package)."""
    tau: float | None = None
    """Look-ahead of the analytic lead, the future target or the feedforward, in seconds
    (default: each one's tuned value)."""
    ilc: ILCConfig = field(default_factory=ILCConfig)
    """The ILC oracle's settings (defaults chosen on the tuning seeds)."""
    shape: str | None = None
    """Force the trajectory shape (circle, fig8, fly) instead of drawing it from the seed."""
    duration: float = 5.0
    """Episode length in seconds (at most 1,000)."""
    video: Path | None = None
    """Render the single episode offscreen to this MP4 instead of opening the viewer."""
    compare: tuple[Literal["classical", "analytic", "policy", "ilc"], ...] | None = None
    """With --video: two controllers side by side on the same seed, e.g. --compare classical
    analytic. --compare alone: classical beside --controller (the policy if that is classical)."""
    stochastic: bool = False
    """Sample policy actions instead of taking the mean."""
    env: EnvOverrides = field(default_factory=EnvOverrides)  # type: ignore[valid-type]
    """Env settings for this evaluation (only the flags given), over the model's. A model's
    training-only settings (observation noise, latency, termination on self-collision) are
    not inherited: give them here to evaluate under them."""
    rollouts_dir: Path = Path("rollouts")
    """Root folder of rollout sets."""
    force: bool = False
    """Write into a --prefix that holds another controller's or model's rollouts (those files
    are deleted first, so the set never mixes two), or replace an existing --video."""


MAX_DURATION_S = 1000.0


def _validate(args: Args):
    import math

    from .. import trajectory
    from ..errors import check_plain_name
    from ..seeds import check_seed, parse_seed_range

    seeds = parse_seed_range(args.seeds) if args.seeds is not None else None
    check_plain_name(args.prefix, "--prefix")
    if args.seed is not None:
        check_seed(args.seed)
    if args.shape is not None and args.shape not in trajectory.SHAPES:
        raise UserError(f"unknown shape {args.shape!r}" + did_you_mean(args.shape, trajectory.SHAPES))
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION_S):
        raise UserError(f"--duration must be a number of seconds in (0, {MAX_DURATION_S:g}], "
                        f"got {args.duration}")
    if args.tau is not None and not (math.isfinite(args.tau) and 0 <= args.tau <= 1.0):
        raise UserError(f"--tau must be a number of seconds in [0, 1], got {args.tau}")
    if args.compare is not None and args.video is None:
        raise UserError("--compare renders a video: add --video out.mp4")
    if args.compare and len(args.compare) != 2:
        raise UserError(f"--compare takes two controllers (or none), got {' '.join(args.compare)}")
    if args.video is not None and args.video.exists() and not args.force:
        raise UserError(f"{args.video} exists; choose another --video path, or add --force to "
                        "replace it")
    overrides = given(args.env)
    EnvConfig().merged(overrides)  # a bad value is one clear line before any work
    return seeds, overrides


def _steps(args: Args) -> int:
    from ..core import control_dt

    return int(round(args.duration / control_dt()))


def _controller(args: Args, name: str, overrides: dict, model_for_env: bool = False):
    model = args.model if (args.model is not None or not model_for_env) else None
    ctrl = harness.build(name, _steps(args), model, overrides, args.tau, args.stochastic,
                         args.ilc)
    if ctrl.dropped:
        print(f"note: evaluating without the model's training-only settings "
              f"{', '.join(ctrl.dropped)} (give --env.* to evaluate under them)")
    return ctrl


def write_rollouts(args: Args, seeds: list[int], overrides: dict) -> None:
    ctrl = _controller(args, args.controller, overrides)
    n = harness.write_set(ctrl, seeds, args.shape, args.rollouts_dir, args.prefix, args.force)
    print(f"wrote {n} rollouts to {args.rollouts_dir / args.prefix}/")


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
    from ..env import PandaLeadEnv
    from ..rollout import record

    names = compare_pair(args) or (args.controller,)
    # Each controller is built as if run alone, so its meta (and the label drawn from it) says
    # what really drove it; every side then plays the policy's env (from its sidecar) when one
    # side is the policy, so both track the same task.
    built = {n: _controller(args, n, overrides, model_for_env=True) for n in dict.fromkeys(names)}
    config = built["policy"].config if "policy" in built else built[names[0]].config
    env = PandaLeadEnv(config, render_mode="rgb_array")
    try:
        rollouts = [record(env, built[n].act_for([seed], [args.shape]), seed, args.shape,
                           built[n].meta) for n in names]
        out = Path(args.video)
        video.write(out, rollouts, env.core.model)  # a failed write is a UserError, old file kept
    except KeyboardInterrupt:
        raise UserError(f"interrupted; {args.video} was not written (any previous file is "
                        "intact)") from None
    finally:
        env.close()
    pairs = zip(names, rollouts, strict=True)
    summary = ", ".join(f"{n} {100 * r.error.mean():.2f} cm" for n, r in pairs)
    print(f"seed {seed} ({rollouts[0].shape}): mean error {summary}; wrote {out}")


def watch(args: Args, seed: int, overrides: dict) -> None:
    from ..display import has_display

    # The controller first: a missing or mismatched model is the user's first problem to
    # hear about, not the display that would then show it.
    ctrl = _controller(args, args.controller, overrides)
    if not has_display():
        raise UserError("no display for the viewer: record instead with --video out.mp4, or "
                        "write rollout files with --seeds 0-9 --prefix NAME")
    import time

    import mujoco.viewer

    from ..env import PandaLeadEnv

    act = ctrl.act_for([seed], [args.shape])
    env = PandaLeadEnv(ctrl.config)
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


@exit_on_user_error  # a bad command line is one line too (parse_cli)
def run_controller_cli(default_controller: str, default_prefix: str, argv, prog: str,
                       description: str | None = None) -> None:
    from . import models as model_commands

    if model_commands.wants(argv):  # --restore-sidecar, --adopt: the model-file commands
        model_commands.main(list(argv), prog)
        return
    defaults = Args(controller=default_controller, prefix=default_prefix)
    args = parse_cli(Args, argv, default=defaults, prog=prog, description=description)
    _run(args)


def random_test_seed(rng=None) -> int:
    """A random seed of the test set (seeds.TEST_SEEDS, 0-999): a seed drawn from 0..2^31-1
    was a training trajectory's (TRAIN_SEED_LOW and up) 99.5% of the time."""
    from ..seeds import TEST_SEEDS

    rng = np.random.default_rng() if rng is None else rng
    return int(TEST_SEEDS[int(rng.integers(len(TEST_SEEDS)))])


@exit_on_user_error  # UserError, ModelError, bad seeds/shapes: one line, exit 2; bugs keep traces
def _run(args: Args) -> None:
    seeds, overrides = _validate(args)
    if seeds is not None:
        write_rollouts(args, seeds, overrides)
    else:
        seed = args.seed if args.seed is not None else random_test_seed()
        if args.video:
            write_video(args, seed, overrides)
        else:
            watch(args, seed, overrides)


# --- eval's and ikpd's command lines (panda_lead.cli.main dispatches to them) ---------------

EVAL_HELP = """Run a policy (or a baseline) on seeds: watch it, record a video, or write rollout files.

    {cmd} --seed 7                                       # viewer (needs a display)
    {cmd} --seed 7 --video videos/h_7.mp4                # offscreen MP4, any machine
    {cmd} --seed 7 --video videos/cmp.mp4 --compare      # classical | policy
    {cmd} --seeds 0-99 --prefix eval_h --model archive/{headline}.zip
    {cmd} --seeds 0-99 --prefix analytic --controller analytic

The env is rebuilt from the model's sidecar, so any archived model runs on any seed set
(default: the headline model, archive/{headline}.zip).

Model-file commands (each has its own --help):

    {cmd} --adopt PATH.zip --name NAME [--env.X ...]   # a model trained elsewhere -> archive/NAME
    {cmd} --model archive/NAME.zip --restore-sidecar   # rewrite NAME.json from the zip
"""

IKPD_HELP = """The classical baseline (IK+PD, zero lead) or the analytic lead, in one command.

    {cmd} --seeds 0-99 --prefix ikpd                        # classical, rollout files
    {cmd} --seeds 0-99 --prefix analytic --controller analytic
    {cmd} --seed 7 --video videos/classical_7.mp4           # offscreen MP4

The same command line as eval (panda_lead.cli.run); only the default controller differs.
"""


def eval_command(argv: list[str], prog: str = "eval.py", cmd: str = "uv run eval.py") -> None:
    from ..models import DEFAULT_MODEL

    run_controller_cli(default_controller="policy", default_prefix="eval", argv=argv,
                       prog=prog, description=EVAL_HELP.format(cmd=cmd, headline=DEFAULT_MODEL))


def ikpd_command(argv: list[str], prog: str = "ikpd.py", cmd: str = "uv run ikpd.py") -> None:
    run_controller_cli(default_controller="classical", default_prefix="ikpd", argv=argv,
                       prog=prog, description=IKPD_HELP.format(cmd=cmd))


if __name__ == "__main__":  # python -m panda_lead.cli.run: eval's command line
    import sys

    eval_command(sys.argv[1:], prog="python -m panda_lead.cli.run",
                 cmd="python -m panda_lead.cli.run")
