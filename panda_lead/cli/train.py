"""Train a PPO lead policy: `uv run train.py [--preset v5] [--timesteps N] [--archive NAME]`.

One folder per run under runs/: config.json (the resolved config), command.txt, tb/
(TensorBoard), checkpoints/, best_model.zip (lowest evaluation-set tracking error) and
final_model.zip, each model with its sidecar. Ctrl-C or SIGTERM saves the model and prints how
to resume (`--resume RUN_FOLDER`). `--preset NAME` starts from a preset; every flag given
overrides it, and `--preset NAME --help` shows the preset's values.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ..errors import UserError, exit_on_user_error, parse_cli
from ..training.config import (
    PROFILES,
    REFERENCE_HPARAMS,
    RESUME_MAY_CHANGE,
    TrainArgs,
    TrainConfig,
    flag,
    read_run_config,
)
from ..training.presets import get_preset, preset_table


def parse_args(argv: list[str], prog: str | None = None, description: str | None = None
               ) -> TrainArgs:
    """The command line -> TrainArgs. ``--preset NAME`` (or ``--resume RUN``: the run's
    config) and ``--reference-hparams`` choose the defaults; every flag given overrides them,
    even when it equals the plain default. ``--preset v5 --help`` shows v5's values."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--preset")
    pre.add_argument("--resume")
    pre.add_argument("--reference-hparams", action="store_true")
    pre.add_argument("--profile", default="auto")
    pre.add_argument("--device", default="cpu")
    known, _ = pre.parse_known_args(argv)
    for flag_, given in (("--reference-hparams", known.reference_hparams),
                         ("--profile", known.profile != "auto")):
        if known.resume and given:
            raise UserError(f"{flag_} changes what a run learns; --resume continues a run with "
                            "its own config (start a new run instead)")
    if known.resume:
        base = read_run_config(Path(known.resume))
    elif known.preset:
        base = get_preset(known.preset)
    else:
        base = TrainConfig()
    if known.reference_hparams:
        base = dataclasses.replace(base, **REFERENCE_HPARAMS)
    profile = machine_profile(known.profile, known.device, bool(known.resume))
    base = dataclasses.replace(base, **PROFILES[profile])  # cpu: {}, the defaults as they are
    default = TrainArgs(**{f.name: getattr(base, f.name) for f in dataclasses.fields(TrainConfig)},
                        reference_hparams=known.reference_hparams, profile=profile)
    args = parse_cli(TrainArgs, argv, default=default, prog=prog, description=description)
    if known.resume:
        changed = [f.name for f in dataclasses.fields(TrainConfig)
                   if f.name not in RESUME_MAY_CHANGE and getattr(args, f.name) != getattr(base, f.name)]
        if changed:
            raise UserError(f"--resume continues the run with its own config; "
                            f"{', '.join('--' + flag(c) for c in changed)} cannot change "
                            "(start a new run instead)")
    return args


def machine_profile(profile: str, device: str, resuming: bool) -> str:
    """The profile a command line trains with: the one named, else gpu for a CUDA device;
    cpu (no change) when resuming, where the run's own config decides."""
    if profile not in ("auto", *PROFILES):
        raise UserError(f"--profile must be one of auto, {', '.join(PROFILES)}; got {profile!r}")
    if resuming:
        return "cpu"
    if profile == "auto":
        return "gpu" if device.startswith("cuda") else "cpu"
    return profile


def describe_profile(args: TrainArgs) -> str:
    """One line: which machine profile the run trains with and the values it sets."""
    if args.resume:
        return "profile: the resumed run's own config"
    values = ", ".join(f"{flag(k)} {getattr(args, k)}" for k in PROFILES["gpu"])
    return f"profile {args.profile} (training/config.py PROFILES; flags given override): {values}"


@exit_on_user_error
def run(argv: list[str], prog: str = "train.py") -> None:
    description = f"{__doc__}\nPresets:\n{preset_table()}"
    args = parse_args(argv, prog=prog, description=description)
    if args.profile != "cpu" or args.device != "cpu":  # say which one a CUDA run trains with
        print(describe_profile(args), flush=True)
    # After the command line is checked: the loop imports torch and stable-baselines3 (~5 s).
    from ..training.loop import TrainingInterrupted, train

    try:
        train(args)
    except TrainingInterrupted as exc:
        raise SystemExit(128 + exc.signum) from None


def main(argv: list[str] | None = None, prog: str = "train.py") -> None:
    import sys

    run(sys.argv[1:] if argv is None else argv, prog)
