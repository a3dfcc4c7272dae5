"""Tune the analytic lead's look-ahead tau on the tuning seeds (never the test seeds).

    uv run studies/tau.py                 # tau 0.00-0.10 s in 0.01 s steps, 5 s episodes
    uv run studies/tau.py --substep-ik > results/studies/tau/tau_500hz.txt   # with the IK at 500 Hz

Every tau plays all tuning seeds as one batch; the best mean error wins. The result is
controllers.DEFAULT_TAU (0.04 s), which the analytic baseline uses everywhere. With
--substep-ik the IK runs at every physics substep (500 Hz, the reference work's rate) and the
best tau there is what the 500 Hz analytic baseline uses (studies/runs.py reads it from
results/studies/tau/tau_500hz.txt).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    duration: float = 5.0
    """Episode length in seconds."""
    taus: tuple[float, ...] = tuple(np.round(np.arange(0.0, 0.1001, 0.01), 3).tolist())
    """Candidate look-aheads (s)."""
    substep_ik: bool = False
    """Run the IK before every physics substep (500 Hz) instead of once per control step."""


def main(args: Args) -> None:
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.core import control_dt
    from panda_lead.rollout import record_many
    from panda_lead.seeds import TUNE_SEEDS

    config = EnvConfig(episode_steps=int(round(args.duration / control_dt())),
                       ik={"substep_ik": args.substep_ik})
    rate = "500 Hz (every substep)" if args.substep_ik else "100 Hz (every control step)"
    print(f"tuning tau on {len(TUNE_SEEDS)} seeds {TUNE_SEEDS[0]}-{TUNE_SEEDS[-1]}, IK at {rate}")
    errors = {}
    for tau in args.taus:
        rollouts = record_many(config, controllers.make_analytic(float(tau)), TUNE_SEEDS)
        errors[tau] = 100 * float(np.mean([r.error.mean() for r in rollouts]))
        print(f"tau {tau:.2f} s: mean error {errors[tau]:.2f} cm", flush=True)
    best = min(errors, key=errors.get)
    print(f"best tau {best:.2f} s ({errors[best]:.2f} cm); in use: {controllers.DEFAULT_TAU} s")


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
