"""Compare two rollout sets seed by seed: `uv run metrics.py --prefix-a ikpd --prefix-b eval`.

A face of the package: the numbers are panda_lead.metrics, this command line
panda_lead.cli.metrics.
"""

import sys

if __name__ == "__main__":
    from panda_lead.cli.metrics import main

    sys.exit(main(sys.argv[1:]))
