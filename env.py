"""`import env` registers PandaLead-v0 (so do RL Zoo's `--gym-packages env` and `import panda_lead`).

A face of the package: the env is panda_lead.env, its settings panda_lead.config.EnvConfig,
the natively batched vector env panda_lead.vector. Run, it prints the env's manual
(`uv run env.py --help`, `--check`; installed: `panda-lead env`).
"""

import sys

from panda_lead.config import EnvConfig  # noqa: F401
from panda_lead.env import PandaLeadEnv  # noqa: F401

if __name__ == "__main__":
    from panda_lead.cli.env import main

    sys.exit(main(sys.argv[1:], prog="env.py"))
