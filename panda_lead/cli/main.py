"""`panda-lead`, the command a pip install gives: one command, the six root scripts as its
subcommands (``panda-lead eval --seed 7 --video v.mp4`` is ``uv run eval.py --seed 7 --video
v.mp4`` in the checkout; each subcommand has the script's flags and ``--help``).

Why one command and not six ``panda-lead-*``: the subcommands are the root scripts by name,
so the docs' commands translate word for word; ``panda-lead --help`` lists them all in one
place; and one name is put on the PATH instead of six.

The help texts of eval and ikpd live here (not in the root scripts' docstrings) so that the
installed package, which has no root scripts, prints the same help.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from ..errors import UserError, did_you_mean, exit_on_user_error


def eval_command(argv: list[str], prog: str = "eval.py", cmd: str = "uv run eval.py") -> None:
    """eval's command line (panda_lead.cli.run, imported when it runs: `panda-lead --help` loads
    no simulation)."""
    from .run import eval_command as command

    command(argv, prog, cmd)


def ikpd_command(argv: list[str], prog: str = "ikpd.py", cmd: str = "uv run ikpd.py") -> None:
    """ikpd's command line (panda_lead.cli.run, imported when it runs)."""
    from .run import ikpd_command as command

    command(argv, prog, cmd)


def _train(argv: list[str], prog: str, cmd: str) -> None:
    from .train import main

    main(argv, prog=prog)


def _metrics(argv: list[str], prog: str, cmd: str) -> int:
    from .metrics import main

    return main(argv, prog=prog)


def _env(argv: list[str], prog: str, cmd: str) -> int:
    from .env import main

    return main(argv, prog=prog)


def _trajectory(argv: list[str], prog: str, cmd: str) -> int:
    from .trajectory import main

    return main(argv, prog=prog)


# name -> (what it does, its entry); the names are the root scripts'
COMMANDS: dict[str, tuple[str, Callable]] = {
    "train": ("train a PPO lead policy (train.py)", _train),
    "eval": ("run a policy or a baseline on seeds: viewer, video, rollout files; adopt a "
             "model (eval.py)", eval_command),
    "ikpd": ("the classical IK+PD baseline or the analytic lead (ikpd.py)", ikpd_command),
    "metrics": ("compare two rollout sets seed by seed (metrics.py)", _metrics),
    "env": ("the env's manual, or a check of it (env.py)", _env),
    "trajectory": ("an analytic target trajectory as text or a plot (trajectory.py)",
                   _trajectory),
}


def usage(prog: str = "panda-lead") -> str:
    width = max(map(len, COMMANDS))
    lines = [f"usage: {prog} COMMAND [flags]   ({prog} COMMAND --help for its flags)", "",
             "Does a learned Cartesian lead make a classical IK+PD Panda track a fast target "
             "better?", "", "commands:"]
    lines += [f"  {name:{width}}  {what}" for name, (what, _) in COMMANDS.items()]
    return "\n".join(lines)


@exit_on_user_error
def _unknown(name: str, prog: str) -> None:
    raise UserError(f"unknown command {name!r}" + did_you_mean(name, COMMANDS)
                    + f"; see {prog} --help")


def main(argv: list[str] | None = None, prog: str = "panda-lead") -> int:
    """The console script: ``panda-lead COMMAND [flags]``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage(prog))
        return 0
    if argv[0] == "--version":
        from .. import __version__

        print(f"panda-lead {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        _unknown(name, prog)
    sub = f"{prog} {name}"
    return COMMANDS[name][1](rest, prog=sub, cmd=sub) or 0


if __name__ == "__main__":
    sys.exit(main())
