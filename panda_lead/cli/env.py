"""The env's manual, or a quick check that it works here.

    uv run env.py                  # the manual of PandaLead-v0 (spaces, reward, settings)
    uv run env.py --check          # Gymnasium's env checker and one short episode

``import env`` (RL Zoo's ``--gym-packages env``) only registers the env; this command line runs
when the script is run.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

from ..errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    check: bool = False
    """Run Gymnasium's check_env on the env (headless-safe: skip_render_check=True) and one
    20-step episode, and say what was checked."""


@exit_on_user_error
def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    args = parse_cli(Args, argv, prog=prog, description=__doc__)
    from ..env import PandaLeadEnv

    if not args.check:
        print(inspect.cleandoc(PandaLeadEnv.__doc__))
        return 0
    import warnings

    import numpy as np
    from gymnasium.utils.env_checker import check_env

    env = PandaLeadEnv(episode_steps=20)
    with warnings.catch_warnings():
        # Gymnasium's own MuJoCo envs use unbounded observation boxes too; not a defect.
        warnings.filterwarnings("ignore", message=".*observation space (min|max)imum value")
        check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0, options={"traj_seed": 0})
    steps, errors, done = 0, [], False
    while not done:
        obs, _, terminated, truncated, step_info = env.step(np.zeros(3, np.float32))
        errors.append(step_info["distance"])
        steps, done = steps + 1, terminated or truncated
    env.close()
    print(f"ok: check_env passed; test seed 0 ({info['shape']}), {steps} steps of the classical "
          f"controller, mean error {100 * np.mean(errors):.2f} cm")
    return 0
