"""`import env` registers PandaLead-v0 (so do RL Zoo's `--gym-packages env` and `import panda_lead`).

A face of the package: the env is panda_lead.env, its settings panda_lead.config.EnvConfig,
the natively batched vector env panda_lead.vector.
"""

from panda_lead.config import EnvConfig  # noqa: F401
from panda_lead.env import PandaLeadEnv  # noqa: F401
