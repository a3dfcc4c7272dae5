"""The classical baseline (IK+PD, zero lead) or the analytic lead, in one command.

A face of the package: `uv run ikpd.py --help` prints the examples and every flag (the same
command line as eval.py, panda_lead.cli.run; only the default controller differs); installed,
the same command is `panda-lead ikpd`. Nothing imports this script.
"""

import os
import sys

from panda_lead.cli.main import ikpd_command

if __name__ == "__main__":
    ikpd_command(sys.argv[1:], prog=os.path.basename(__file__))
