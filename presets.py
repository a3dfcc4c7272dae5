"""The reference work's ladder of versions, reproducible by name: `uv run train.py --preset v5`.

Each preset is a set of env keyword arguments (see `env.PandaLeadEnv`), PPO overrides and a
training budget. Anything a preset does not set keeps the env's or train.py's default.
"""

from __future__ import annotations

import difflib

OBS_12 = ("ee_pos", "ee_vel", "target_pos", "target_vel")
OBS_15 = OBS_12 + ("target_acc",)
OBS_29 = OBS_15 + ("joint_pos", "joint_vel")

# Penetration is millimetres deep, so the weight is large: 1 cm deep costs 1 per step, about
# ten times the distance term at a typical 10 cm error.
COLLISION_WEIGHT = 100.0

PRESETS: dict[str, dict] = {
    "v1": dict(doc="circles only, 12-D observation (no target_acc)",
               env=dict(obs_features=OBS_12, shapes=("circle",)), timesteps=1_000_000),
    "v2": dict(doc="all shapes + self-collision penalty",
               env=dict(obs_features=OBS_12, w_collision=COLLISION_WEIGHT)),
    "v3": dict(doc="v2 without the collision penalty", env=dict(obs_features=OBS_12)),
    "v4": dict(doc="v3 + entropy bonus ent_coef 0.01",
               env=dict(obs_features=OBS_12), ppo=dict(ent_coef=0.01)),
    "v5": dict(doc="v3 + target_acc in the observation (15-D)", env=dict(obs_features=OBS_15)),
    "v6": dict(doc="v5 + joint angles and velocities (29-D) + early termination on self-collision",
               env=dict(obs_features=OBS_29, terminate_on_collision=True)),
    # The termination penalty (50) outweighs what the rest of an episode can still earn (at most
    # ~1 per step from the tracking term, minus the distance), so ending early never pays.
    "v7": dict(doc="v6 + exponential tracking reward + termination penalty",
               env=dict(obs_features=OBS_29, terminate_on_collision=True, w_tracking=1.0,
                        w_alive=0.0, w_termination=50.0)),
    "v9": dict(doc="v5 + action-change penalty (weight 0.1) + 5 s episodes",
               env=dict(obs_features=OBS_15, w_action_change=0.1, episode_steps=500)),
    # This repo's own configuration (not in the reference ladder): the policy sees its previous
    # action, so the action-change penalty is a Markov cost it can plan against; the penalty
    # keeps the lead smooth (jerk), the collision term keeps the arm out of itself.
    "smooth": dict(doc="v5 + prev_action observed + action-change penalty 0.5 + collision "
                       "penalty + 5 s episodes (this repo's own)",
                   env=dict(obs_features=OBS_15 + ("prev_action",), w_action_change=0.5,
                            w_collision=COLLISION_WEIGHT, episode_steps=500)),
}
for _p in PRESETS.values():
    _p.setdefault("ppo", {})
    _p.setdefault("timesteps", 5_000_000)


def get_preset(name: str) -> dict:
    if name not in PRESETS:
        close = difflib.get_close_matches(name, list(PRESETS), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown preset {name!r}{hint} (valid: {', '.join(PRESETS)})")
    return PRESETS[name]
