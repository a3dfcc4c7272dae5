"""Run a policy (or a baseline) on seeds: watch it, record a video, or write rollout files.

A face of the package: `uv run eval.py --help` prints the examples and every flag (the help
text is panda_lead.cli.run.EVAL_HELP, the command line panda_lead.cli.run); installed,
the same command is `panda-lead eval`.
"""

import os
import sys

from panda_lead.cli.main import eval_command

if __name__ == "__main__":
    eval_command(sys.argv[1:], prog=os.path.basename(__file__))
