"""The classical baseline (IK+PD, zero lead) or the analytic lead, in one command.

    uv run ikpd.py --seeds 0-99 --prefix ikpd                        # classical, rollout files
    uv run ikpd.py --seeds 0-99 --prefix analytic --controller analytic
    uv run ikpd.py --seed 7 --video videos/classical_7.mp4           # offscreen MP4

The same command line as eval.py (panda_lead.cli.run); only the default controller differs.
Nothing imports this script.
"""

import os
import sys

from panda_lead.cli.run import run_controller_cli

if __name__ == "__main__":
    run_controller_cli(default_controller="classical", default_prefix="ikpd", argv=sys.argv[1:],
                       prog=os.path.basename(__file__), description=__doc__)
