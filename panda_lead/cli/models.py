"""Model-file commands of eval.py: repair a model's JSON sidecar from the sidecar its zip
carries.

    uv run eval.py --model archive/NAME.zip --restore-sidecar
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import tyro

from ..errors import exit_on_user_error
from ..models import restore_sidecar, verify

COMMANDS = ("--restore-sidecar",)


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


@exit_on_user_error
def run(argv: list[str], prog: str) -> None:
    args = tyro.cli(RestoreArgs, args=argv, prog=prog, description=__doc__)
    path = restore_sidecar(args.model)
    verify(args.model)
    print(f"wrote {path} from the sidecar {args.model} carries")


def main(argv: list[str], prog: str) -> None:
    run(argv, prog)
