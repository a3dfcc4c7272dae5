"""What the archived models are for, in one place: the README's headline, the model a real arm
should run, and the ones they replaced.

A model's card (``training.archive.write_card``) says its role, and studies/results_steps.py
takes the headline's and the hardware model's names from here, so the cards and the results
cannot name different models. When a role moves: change it here, rewrite both cards
(``rewrite_cards([old, new])``), and follow results_steps.py's note on the headline's tables.
The figures quoted are the committed tables' (test seeds 0-999, which no training or
selection saw); the README has the story.
"""

from __future__ import annotations

# chosen by issue 37's selection rule (docs/training.md) among the presets' budget's studies
HEADLINE = "v5_err_decay_kept_s3"
# the first lead to meet all six of issue 36's targets (README, "Which model for a real arm")
HARDWARE = "deploy_large_batch_curv10_actions_stack4_20m_late100_lp10"

_HARDWARE_TABLE = ("results/studies/deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m/"
                   "lowpass1000/deploy.md")

ROLES: dict[str, str] = {
    HEADLINE: (
        "**The headline model** (README, \"The answer\"; since 2026-11-27, 22:00 UTC), chosen by "
        "the selection rule on the 2,378 selection trajectories: the first model of the first "
        "study trained at the presets' budget. On the "
        "1,000 test seeds 1.80 cm mean error against the analytic lead's 3.98, in the nominal "
        "world (no latency, exact sensors). For a real arm run "
        f"`{HARDWARE}` instead: at 10 ms of latency this one tracks 0.99 cm worse than the "
        "analytic lead (results/headline/delay.md, 500 test seeds)."),
    HARDWARE: (
        "**The recommended model for a real arm** (README, \"Which model for a real arm\"; since "
        "2026-11-28, 10:50 UTC): the first lead to meet all six of issue 36's targets on the "
        "1,000 test seeds, with the 10 Hz low-pass on its lead where the sensors are noisy. "
        "Against the analytic lead: 1.75 against 3.98 cm without delay, 2.27 against 4.88 at 10 "
        "ms of latency and 3.77 against 6.60 at 30 ms, less tip jerk in every condition (413 "
        "against 500 m/s^3 without delay); under 1 cm of sensor noise 2.26 cm and 567 m/s^3 "
        "against the Kalman-filtered analytic lead's 4.13 and 617; the Panda's 1 kHz limits "
        "accept it on 151 / 140 / 136 of 1,000 paths at 0 / 10 / 30 ms against the analytic "
        "lead's 144 / 140 / 133 (as many, not more: no difference shown). Every row, with CIs "
        f"and the rivals given the same knowledge: `{_HARDWARE_TABLE}` "
        "(`uv run studies/deploy.py`, docs/deploy.md). Run it on the collision-aware IK "
        "(`--env.ik.clearance 0.03`): on the plain IK its study's five seeds touch themselves in "
        "99 of 5,000 test episodes, on that IK in 5, for 0.04 cm of settled error (README)."),
    "deploy_large_batch_curv10_actions_stack4_15m_lp10": (
        "Recommended for a real arm from 2026-11-28, 05:30 to 10:50 UTC; replaced by "
        f"`{HARDWARE}` (at 30 ms of latency the arm's limits accepted it on 131 of 1,000 paths "
        "against the analytic lead's 133: the one target it missed)."),
    "deploy_large_batch_curv10_actions_stack4_10m_lp10": (
        "Recommended for a real arm on 2026-11-28 until 05:30 UTC; replaced, now by "
        f"`{HARDWARE}`."),
    "deploy_large_batch_curv10_10m_lp10": (
        "Recommended for a real arm from 2026-11-27 (evening) into 2026-11-28; replaced, now by "
        f"`{HARDWARE}`."),
    "v5_err_decay_s4": (
        "The headline model until 2026-11-27, 22:00 UTC (issue 36's \"today's headline\"); "
        f"replaced by `{HEADLINE}` under the selection rule."),
}


def role(name: str) -> str | None:
    """The role of the archived model NAME, or None when it has none."""
    return ROLES.get(name)
