"""panda_lead: does a learned Cartesian lead help a classical IK+PD Panda track a fast target?

``import panda_lead`` registers the env under two ids, ``PandaLead-v0`` and
``panda_lead/PandaLead-v0`` (Gymnasium's namespaced form, also reachable as
``gymnasium.make("panda_lead:PandaLead-v0")`` without importing anything first). The entry
points are strings, so registering imports neither MuJoCo nor the env until one is made.

The library, one concept per module, in the order data flows through it:
trajectory, ikconfig -> config -> core (+ clearance) -> task (+ the single env's fast path,
core_one, task_one) -> env, vector, sb3_vecenv -> controllers
(+ ilc) -> rollout -> models -> training, metrics, video -> cli.
"""

from __future__ import annotations

import gymnasium as gym

from .display import choose_gl_backend

# Every submodule import runs this first, so MuJoCo (which reads MUJOCO_GL once, at its first
# import) renders offscreen through EGL on a headless machine whichever module comes first.
choose_gl_backend()

__version__ = "0.2.0"

ENV_ID = "PandaLead-v0"
_ENTRY = "panda_lead.env:PandaLeadEnv"
_VECTOR_ENTRY = "panda_lead.vector:PandaLeadVecEnv"


def _register() -> None:
    # The episode length has one home, EnvConfig.episode_steps: the env truncates itself and
    # reports spec.max_episode_steps from it (see env.py), so no TimeLimit is registered that
    # could disagree with it.
    for env_id in (ENV_ID, f"panda_lead/{ENV_ID}"):
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=_ENTRY, vector_entry_point=_VECTOR_ENTRY)


_register()
