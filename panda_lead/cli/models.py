"""Model-file commands of eval.py: adopt a model trained elsewhere into the archive, or repair
a model's JSON sidecar from the sidecar its zip carries.

    uv run eval.py --adopt logs/ppo/PandaLead-v0_1/PandaLead-v0.zip --name zoo_v0 [--env.X ...]
    uv run eval.py --model archive/NAME.zip --restore-sidecar
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import UserError, exit_on_user_error, parse_cli
from ..models import restore_sidecar, verify
from .overrides import EnvOverrides, given

COMMANDS = ("--restore-sidecar", "--adopt")


def wants(argv: list[str]) -> bool:
    """Whether eval.py's command line asks for one of these commands."""
    return any(a.split("=")[0] in COMMANDS for a in argv)


@dataclass
class RestoreArgs:
    model: Path
    """The model zip whose JSON sidecar to rewrite from the sidecar it carries."""
    restore_sidecar: bool = True
    """Rewrite MODEL.json from the sidecar inside MODEL.zip (after an interrupted write, or a
    JSON edited or lost). Nothing else is read or written."""


@dataclass
class AdoptArgs:
    """Adopt an SB3 PPO zip trained outside this repo (RL Baselines3 Zoo, a CleanRL-to-SB3
    conversion, your own script) as archive/NAME.zip with its sidecar and a model card. Nothing
    in the zip is unpickled: its `data` is read as JSON, its weights as tensors only; the policy
    and spaces are checked against the env config (the env's defaults plus the --env.* flags
    given). Adopt an RL Zoo model where RL Zoo wrote it, so that its config.yml (env_kwargs,
    normalize) and any vecnormalize.pkl are checked too."""

    adopt: Path
    """The SB3 PPO zip to adopt."""
    name: str
    """Archive name: writes archive/NAME.zip, NAME.json and NAME.md (in the working folder)."""
    env: EnvOverrides = field(default_factory=EnvOverrides)  # type: ignore[valid-type]
    """The env settings the model was trained with, over the env's defaults (only the flags
    given), e.g. --env.obs-features ee_pos ee_vel target_pos target_vel; over the model's own
    sidecar where it has one (a model of this repo)."""
    force: bool = False
    """Replace an existing archive/NAME."""


@exit_on_user_error
def restore(argv: list[str], prog: str) -> None:
    args = parse_cli(RestoreArgs, argv, prog=prog, description=__doc__)
    path = restore_sidecar(args.model)
    verify(args.model)
    print(f"wrote {path} from the sidecar {args.model} carries")


@exit_on_user_error
def adopt(argv: list[str], prog: str) -> None:
    from ..adopt import adopt as adopt_model

    args = parse_cli(AdoptArgs, argv, prog=prog)
    adopt_model(args.adopt, args.name, given(args.env), force=args.force)


def main(argv: list[str], prog: str) -> None:
    asked = {a.split("=")[0] for a in argv} & set(COMMANDS)
    if len(asked) > 1:
        exit_on_user_error(_both)(sorted(asked))
    if "--adopt" in asked:
        adopt(argv, prog)
    else:
        restore(argv, prog)


def _both(asked: list[str]) -> None:
    raise UserError(f"{' and '.join(asked)} are separate commands: give one")
