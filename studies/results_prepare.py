"""What the tables read, refreshed before `studies/results.py` (its `all` section) builds them:
each sweep's committed run summaries, the archived models the tables measure, and the rollout
sets of the test seeds. A model is archived only when missing (an archived model is committed
and other results name it); a rollout set is replayed when missing or when the model that
played it is not the archived one (its files' model_sha256 against the model's sidecar)."""

from __future__ import annotations

import glob
import json
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

from results_steps import (
    BY_SELECTION,
    HARDWARE,
    HEADLINE,
    HEADLINE_STUDY,
    LATE100_HAND,
    PRESET_STUDY,
    PREVIOUS,
    PREVIOUS_HEADLINE,
    SHARE_LADDER,
    SMOOTH,
)

# issue 36's large-batch deployment studies (five seeds each, every seed kept)
LARGE_BATCH = ("deploy_large_batch_5m", "deploy_large_batch_n90_5m", "deploy_large_batch_wide_5m",
               "deploy_large_batch_caps30_5m", "deploy_large_batch_wide_n90_5m",
               "deploy_large_batch_from_headline_5m", "deploy_large_batch_continued_5m",
               "deploy_large_batch_limit_continued_5m", "deploy_large_batch_sde_continued_5m",
               "deploy_large_batch_limit_lead_sde_light_continued_5m",
               "deploy_large_batch_curv10_continued_5m",
               "deploy_large_batch_curv10_actions_continued_5m",
               "deploy_large_batch_curv10_split_continued_5m",
               "deploy_large_batch_curv10_actions_stack4_continued_5m",
               "deploy_large_batch_curv10_actions_stack8_continued_5m",
               "deploy_large_batch_curv10_actions_stack4_continued_again_5m",
               "deploy_large_batch_curv10_actions_stack4_finetuned_5m",
               "deploy_large_batch_curv10_actions_stack4_finetuned_n50_5m",
               "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m")
# single-seed pilots (seed 2, the hardware model's), every seed kept: the curvature term's weight
PILOTS = ("deploy_large_batch_curv3_continued_5m", "deploy_large_batch_curv30_continued_5m",
          "deploy_large_batch_curv100_continued_5m")
# the headline study's seeds trained on, with and without the path ahead (issue 37; 5M steps
# on top of v5_err_decay_kept's, train.py --init-from)
CONTINUED = ("v5_err_decay_continued_5m", "v5_err_decay_preview_continued_5m",
             # ... and again with a gentle restart (their own exploration, lr 3e-4)
             "v5_err_decay_finetuned_5m", "v5_err_decay_preview_finetuned_5m")
# the headline's preset trained with the lap-to-lap correction in the loop (issue 37, "a lead of
# another kind" co-adapted: EnvConfig.repetitive_gain; knows the planned path)
LOOPED = "v5_err_decay_repetitive_5m"
# ... and the headline study's five trained seeds trained on gently with it (its control:
# v5_err_decay_finetuned_5m, the same without the correction)
LOOPED_FT = "v5_err_decay_repetitive_finetuned_5m"
# ... and from random weights with the correction it adds observed (repetitive_correction; a
# pilot stopped after two seeds: summaries only)
LOOPED_OBS = "v5_err_decay_repetitive_observed_5m"
# ... and both the headline's preset and the in-loop one on 5 s training episodes (2 s elsewhere:
# the correction acts in training as at test; the plain one is the control)
LONG, LOOPED_LONG = "v5_err_decay_long_5m", "v5_err_decay_repetitive_long_5m"
SUMMARIZED = ["v5", "v5_joint", "climb", "v5_decay", "v5_err", "v5_err_decay", "v5_err_avg_decay",
              "v5_err_decay_smooth", "v5_track", "v5_prev", "v7", "delayed_5m", "noisy_5m",
              "ikfree", "ikfree_long", "ikfree_5m", "err_delayed", "v5_err_decay_wide",
              "v5_err_decay_wide_lr3e-4", "joint_5m", "curriculum_5m", "v9_5m", "ikfree_50m",
              "deploy_lowpass_5m", "preview_5m", "deploy_real_5m", "deploy_kalman_5m",
              "deploy_known_5m", "deploy_nominal_5m", "preview_feedforward_5m",
              "preview_feedforward_settled_5m", "deploy_armfilter_5m", "deploy_caps_5m",
              "deploy_unsmoothed_5m", "deploy_caps_armfilter_5m", "v5_err_decay_kept",
              "v5_err_decay_actions_5m", LOOPED, LOOPED_FT, LOOPED_OBS, LONG, LOOPED_LONG,
              *LARGE_BATCH, *CONTINUED, *PILOTS]
# study -> sweep folders of its later seeds (queue.sh side5m, headline5 and main; a pilot's
# study grown to five seeds under another sweep name)
EXTRA_SEEDS = {"err_delayed": ["err_delayed_s3"], "v9_5m": ["v9_5m_s4"],
               "deploy_caps_armfilter_5m": ["deploy_caps_armfilter_5m_rest"],
               "preview_feedforward_5m": ["preview_feedforward_5m_rest"],
               "deploy_large_batch_curv10_continued_5m": [
                   "deploy_large_batch_curv10_continued_5m_rest"],
               "deploy_large_batch_curv10_actions_stack4_continued_again_5m": [
                   "deploy_large_batch_curv10_actions_stack4_continued_again_5m_rest"],
               **{s: [f"{s}_rest"] for s in ("v5_err_decay_finetuned_5m",
                                             "v5_err_decay_preview_finetuned_5m")},
               **{s: [f"{s}_s45"] for s in ["joint_5m", "curriculum_5m", "v9_5m", PREVIOUS,
                                            PRESET_STUDY, "ikfree_5m"]}}
# archived name -> (study, sweep folders holding its runs)
CHOSEN = {"v5_5m": ("v5", ["v5"]), HEADLINE: (HEADLINE_STUDY, [HEADLINE_STUDY]),
          PREVIOUS_HEADLINE: (PRESET_STUDY, [PRESET_STUDY, f"{PRESET_STUDY}_s45"]),
          PREVIOUS: (PREVIOUS, [PREVIOUS]), SMOOTH: (SMOOTH, [SMOOTH]),
          "ikfree_long": ("ikfree_long", ["ikfree_long"]),
          "delayed_5m": ("delayed_5m", ["delayed_5m"]), "noisy_5m": ("noisy_5m", ["noisy_5m"]),
          "v7_5m": ("v7", ["v7"]), "joint_5m": ("joint_5m", ["joint_5m", "joint_5m_s45"]),
          "deploy_lowpass_5m": ("deploy_lowpass_5m", ["deploy_lowpass_5m"]),
          "preview_5m": ("preview_5m", ["preview_5m"]),
          "preview_feedforward_5m": ("preview_feedforward_5m",
                                     ["preview_feedforward_5m", "preview_feedforward_5m_rest"]),
          "deploy_caps_armfilter_5m": ("deploy_caps_armfilter_5m",
                                       ["deploy_caps_armfilter_5m",
                                        "deploy_caps_armfilter_5m_rest"]),
          "deploy_large_batch_5m": ("deploy_large_batch_5m", ["deploy_large_batch_5m"]),
          "deploy_large_batch_wide_5m": ("deploy_large_batch_wide_5m",
                                         ["deploy_large_batch_wide_5m"]),
          "deploy_large_batch_10m": ("deploy_large_batch_continued_5m",
                                     ["deploy_large_batch_continued_5m"]),
          "deploy_large_batch_curv10_10m": ("deploy_large_batch_curv10_continued_5m",
                                            ["deploy_large_batch_curv10_continued_5m",
                                             "deploy_large_batch_curv10_continued_5m_rest"]),
          "deploy_large_batch_curv10_actions_10m": (
              "deploy_large_batch_curv10_actions_continued_5m",
              ["deploy_large_batch_curv10_actions_continued_5m"]),
          "deploy_large_batch_curv10_actions_stack4_10m": (
              "deploy_large_batch_curv10_actions_stack4_continued_5m",
              ["deploy_large_batch_curv10_actions_stack4_continued_5m"]),
          "deploy_large_batch_curv10_actions_stack4_15m": (
              "deploy_large_batch_curv10_actions_stack4_continued_again_5m",
              ["deploy_large_batch_curv10_actions_stack4_continued_again_5m",
               "deploy_large_batch_curv10_actions_stack4_continued_again_5m_rest"]),
          "deploy_large_batch_curv10_actions_stack4_20m": (
              "deploy_large_batch_curv10_actions_stack4_finetuned_5m",
              ["deploy_large_batch_curv10_actions_stack4_finetuned_5m"]),
          "deploy_large_batch_curv10_actions_stack4_20m_n50": (
              "deploy_large_batch_curv10_actions_stack4_finetuned_n50_5m",
              ["deploy_large_batch_curv10_actions_stack4_finetuned_n50_5m"]),
          "deploy_large_batch_curv10_actions_stack4_20m_late100": (
              "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m",
              ["deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m"]),
          "preview_continued_10m": ("v5_err_decay_preview_continued_5m",
                                    ["v5_err_decay_preview_continued_5m"]),
          LOOPED: (LOOPED, [LOOPED]), LOOPED_FT: (LOOPED_FT, [LOOPED_FT]),
          "preview_finetuned_10m": ("v5_err_decay_preview_finetuned_5m",
                                    ["v5_err_decay_preview_finetuned_5m",
                                     "v5_err_decay_preview_finetuned_5m_rest"])}
KEPT = {"delayed_5m": "delayed_5m*", "err_delayed": "err_delayed*", "noisy_5m": "noisy_5m",
        "v7": "v7", "deploy_lowpass_5m": "deploy_lowpass_5m", "preview_5m": "preview_5m",
        **{s: s for s in ("deploy_real_5m", "deploy_kalman_5m", "deploy_known_5m",
                          "deploy_nominal_5m", "preview_feedforward_settled_5m",
                          "deploy_armfilter_5m", "deploy_caps_5m", "deploy_unsmoothed_5m")},
        "preview_feedforward_5m": "preview_feedforward_5m*",
        "deploy_caps_armfilter_5m": "deploy_caps_armfilter_5m*",
        # the headline's preset retrained with every seed kept (issue 37's re-rank), and issue
        # 36's large-batch studies
        "v5_err_decay_kept": "v5_err_decay_kept", "v5_err_decay_actions_5m": "v5_err_decay_actions_5m",
        LOOPED: LOOPED, LOOPED_FT: LOOPED_FT, LONG: LONG, LOOPED_LONG: LOOPED_LONG,
        **{s: s for s in (*LARGE_BATCH, *CONTINUED, *PILOTS)
           if s not in EXTRA_SEEDS},
        # (a study grown from its pilot under another sweep name: both sweeps' runs)
        **{s: f"{s}*" for s in (*LARGE_BATCH, *CONTINUED) if s in EXTRA_SEEDS}}
# the classical controllers' sets (ikpd.py): prefix -> its flags
BASELINES = {"classical": [], "analytic": ["--controller", "analytic"],
             "feedforward": ["--controller", "feedforward"],
             "feedforward_plan": ["--controller", "feedforward_plan"]}
POLICY_SETS = [HEADLINE, PREVIOUS_HEADLINE, PREVIOUS, "v5_err_decay", "v5_5m", "indep_v5", "ikfree_long",
               "preview_5m", "preview_continued_10m", "preview_finetuned_10m", HARDWARE, LOOPED,
               LOOPED_FT]
# single seeds' models (archive/seeds/<name>.zip) whose test-seed rollouts a table pairs: the
# device pilots on the deployment world's share of nominal episodes (docs/deploy.md)
SEED_POLICY_SETS = SHARE_LADDER
# the ILC oracle's rollout sets (test seeds 0-199): prefix -> the archived model it starts from
ORACLES = {"ilc": HEADLINE, "ilc_preview": "preview_5m",
           "ilc_preview_continued": "preview_continued_10m",
           "ilc_preview_finetuned": "preview_finetuned_10m", "ilc_hardware": HARDWARE,
           "ilc_looped": LOOPED, "ilc_looped_ft": LOOPED_FT}


# online corrections on top of a lead (studies/online_correction.py; settings tuned on the tuning
# seeds for each lead: results/studies/online/tuning_*.md): prefix -> (base, archived model or
# None, kind, gain, advance, smooth); the plain sets of the headline study's five seeds beside
# them; and the oracles restarted from a corrected lead (prefix -> the corrected set it starts
# from, test seeds 0-199)
ONLINE_REPETITIVE = ("repetitive", 0.3, 15, 0)  # tuning_headline.md
ONLINE_HARDWARE = ("repetitive", 0.5, 10, 3)  # tuning_hardware.md
LATE100 = "deploy_large_batch_curv10_actions_stack4_finetuned_late100_5m"  # the hardware study
ONLINE_FEEDFORWARD = ("repetitive", 0.3, 12, 5)  # tuning_feedforward.md (the rival's own)
ONLINE_RESIDUAL = ("repetitive", 0.5, 9, 3)  # tuning_residual.md: the learned residual on it
ONLINE_PLAIN = {**{f"kept_s{k}": f"seeds/v5_err_decay_kept_s{k}" for k in range(1, 6)},
                **{f"residual_s{k}": f"seeds/preview_feedforward_5m_s{k}" for k in range(1, 6)},
                **{f"late100_s{k}": f"seeds/{LATE100}_s{k}" for k in range(1, 6)},
                **{f"long_s{k}": f"seeds/{LONG}_s{k}" for k in range(1, 6)}}
# ... and the five seeds trained with the correction in the loop (their env runs it: played as
# they are, nothing added on top)
LOOPED_SEEDS = {**{f"looped_s{k}": f"seeds/{LOOPED}_s{k}" for k in range(1, 6)},
                **{f"looped_ft_s{k}": f"seeds/{LOOPED_FT}_s{k}" for k in range(1, 6)},
                **{f"looped_long_s{k}": f"seeds/{LOOPED_LONG}_s{k}" for k in range(1, 6)}}
ONLINE = {"headline_repetitive": ("policy", HEADLINE, *ONLINE_REPETITIVE),
          "analytic_repetitive": ("analytic", None, "repetitive", 0.3, 10, 3),  # tuning_analytic
          "hardware_repetitive": ("policy", HARDWARE, *ONLINE_HARDWARE),
          # the model-based feedforward rival's lap-to-lap version (the same knowledge)
          "feedforward_repetitive": ("feedforward", None, *ONLINE_FEEDFORWARD),
          **{f"{p}_repetitive": ("policy", m, *{"late100": ONLINE_HARDWARE,
                                                "residual": ONLINE_RESIDUAL}.get(
                                                    p.split("_s")[0], ONLINE_REPETITIVE))
             for p, m in ONLINE_PLAIN.items()},
          # the in-loop finetuned study's control (the same gentle 5M steps without the
          # correction) with the correction added after training: the like-for-like pair
          **{f"finetuned_s{k}_repetitive": ("policy", f"seeds/v5_err_decay_finetuned_5m_s{k}",
                                            *ONLINE_REPETITIVE) for k in range(1, 6)}}
# ... and under studies/deploy.py's conditions (online_correction.py --condition): through a
# fixed latency of d control steps each way (the correction computed for when it acts) and under
# 1 cm of noise (it reads the measured error; its own setting, tuning_hardware_noise1.md), the
# IK aimed at the target's reading (noise1) or at the plan (noise1_plan, as the rival's): the
# hardware study's five seeds alone and with their correction, and the feedforward rival's
# correction through latency and under noise (its plain pair is `feedforward`: the latency
# delays only the lead's channel, where the rival has nothing, and under noise its IK aims at
# the plan; its correction gets its own setting there, tuning_feedforward_noise1.md)
ONLINE_NOISE1 = ("repetitive", 0.7, 10, 8)  # tuning_hardware_noise1.md
ONLINE_FEEDFORWARD_NOISE1 = ("repetitive", 0.15, 12, 5)  # tuning_feedforward_noise1.md
CONDITION_PLAIN = {f"late100_s{k}_{c}": (f"seeds/{LATE100}_s{k}", c)
                   for c in ("delay1", "delay3", "noise1", "noise1_plan") for k in range(1, 6)}
CONDITION_ONLINE = {
    **{f"late100_s{k}_repetitive_{c}": (ONLINE[f"late100_s{k}_repetitive"], c)
       for c in ("delay1", "delay3") for k in range(1, 6)},
    **{f"late100_s{k}_repetitive_{c}": (("policy", f"seeds/{LATE100}_s{k}", *ONLINE_NOISE1), c)
       for c in ("noise1", "noise1_plan") for k in range(1, 6)},  # (the same setting tuned best
    # with the IK on the plan: tuning_hardware_noise1_plan.md)
    **{f"feedforward_repetitive_{c}": (ONLINE["feedforward_repetitive"], c)
       for c in ("delay1", "delay3")},
    # under noise the rival's IK aims at the plan; only its correction reads the noisy error
    "feedforward_repetitive_noise1": (("feedforward", None, *ONLINE_FEEDFORWARD_NOISE1),
                                      "noise1")}
# ... and gated: not learning from errors farther than 5 cm (tuning_gate.md, selection seeds)
GATE = 0.05
# (prefix -> (spec, condition)), in the ideal world and under latency 3 and noise 1 cm, each
# with the setting the ungated correction has there
GATED = {**{f"late100_s{k}_repetitive_guarded": (ONLINE[f"late100_s{k}_repetitive"], "none")
            for k in range(1, 6)},
         **{f"late100_s{k}_repetitive_guarded_{c}": CONDITION_ONLINE[f"late100_s{k}_repetitive_{c}"]
            for c in ("delay3", "noise1", "noise1_plan") for k in range(1, 6)},
         "hardware_repetitive_guarded": (ONLINE["hardware_repetitive"], "none")}
GATED_ORACLES = {"ilc_hardware_repetitive_guarded": "hardware_repetitive_guarded"}
ONLINE_ORACLES = {"ilc_headline_repetitive": "headline_repetitive",
                  "ilc_hardware_repetitive": "hardware_repetitive"}
SETTINGS = ("kind", "gain", "advance", "smooth")


class Variant(NamedTuple):
    """One registered rollout set of the variant registries (LONG_EPISODES, CLEARANCE, FADED,
    PLANNED), played by _variant_sets: its base controller, archived model (or None), the
    online correction's spec (or None) and gate, the IK's clearance, the correction's fade,
    and whether the planner's hand is on."""
    base: str
    model: str | None
    spec: tuple | None
    gate: float | None
    clearance: float = 0.0
    fade: float | None = None
    plan: bool = False


def _variants(registry: dict) -> dict[str, Variant]:
    return {prefix: Variant(*fields) for prefix, fields in registry.items()}


# what the laps would buy: 10 s episodes (online_correction.py play --duration), test seeds
# 0-199, the archived hardware model and its study's five seeds alone and with the gated
# correction, and the feedforward rival alone and with its own: prefix -> (base, archived model
# or None, the online spec or None, its gate)
LONG_EPISODES = _variants({
    "hardware_10s": ("policy", HARDWARE, None, None),
    "hardware_repetitive_guarded_10s": ("policy", HARDWARE, ONLINE["hardware_repetitive"], GATE),
    **{f"late100_s{k}_10s": ("policy", f"seeds/{LATE100}_s{k}", None, None)
       for k in range(1, 6)},
    **{f"late100_s{k}_repetitive_guarded_10s": ("policy", f"seeds/{LATE100}_s{k}",
                                                ONLINE[f"late100_s{k}_repetitive"], GATE)
       for k in range(1, 6)},
    "feedforward_10s": ("feedforward", None, None, None),
    "feedforward_repetitive_10s": ("feedforward", None, ONLINE["feedforward_repetitive"], None)})
LONG_S, LONG_SEEDS = 10.0, "0-199"
# the collision-aware IK under the lead and the rival alike (online_correction.py --clearance;
# each its own clearance, chosen on the selection seeds: tuning_clearance.md), test seeds 0-999:
# the hardware study's five seeds alone and with the gated correction, the feedforward rival
# alone and with its own (same registry form as LONG_EPISODES, the clearance last)
CLEARANCE_LEAD, CLEARANCE_RIVAL = 0.03, 0.01
CLEARANCE = _variants({
    **{f"late100_s{k}_clear": ("policy", f"seeds/{LATE100}_s{k}", None, None, CLEARANCE_LEAD)
       for k in range(1, 6)},
    **{f"late100_s{k}_repetitive_guarded_clear": ("policy", f"seeds/{LATE100}_s{k}",
                                                  ONLINE[f"late100_s{k}_repetitive"], GATE,
                                                  CLEARANCE_LEAD) for k in range(1, 6)},
    "feedforward_clear": ("feedforward", None, None, None, CLEARANCE_RIVAL),
    "feedforward_repetitive_clear": ("feedforward", None, ONLINE["feedforward_repetitive"], None,
                                     CLEARANCE_RIVAL)})

# the corrections faded in (online_correction.py --fade; online.OnlineCorrection.weight): switched
# on at once their first lap's kink breaks the Panda's joint-2 acceleration limit; the fade,
# chosen on the selection seeds (tuning_fade.md), is the same for the lead's and the rival's.
# Test seeds 0-999, same registry form as CLEARANCE with the fade last
FADE = 0.1
FADED = _variants({
    **{f"late100_s{k}_repetitive_guarded_fade": ("policy", f"seeds/{LATE100}_s{k}",
                                                 ONLINE[f"late100_s{k}_repetitive"], GATE, 0.0,
                                                 FADE) for k in range(1, 6)},
    **{f"late100_s{k}_repetitive_guarded_clear_fade": ("policy", f"seeds/{LATE100}_s{k}",
                                                       ONLINE[f"late100_s{k}_repetitive"], GATE,
                                                       CLEARANCE_LEAD, FADE) for k in range(1, 6)},
    "feedforward_repetitive_fade": ("feedforward", None, ONLINE["feedforward_repetitive"], None,
                                    0.0, FADE),
    "feedforward_repetitive_clear_fade": ("feedforward", None, ONLINE["feedforward_repetitive"],
                                          None, CLEARANCE_RIVAL, FADE)})
# ... and through 3 steps of latency, where the rule chose no fade (every fade cost more than
# its 0.02 cm on the selection seeds) but 0.2 s kept every trajectory the lead alone is accepted
# on there: shown as that trade, labelled not the rule's choice (prefix -> (spec, condition,
# fade)); the correction's setting there is the ungated one (CONDITION_ONLINE)
FADE_DELAY3 = 0.2
FADED_CONDITION = {f"late100_s{k}_repetitive_delay3_fade": (
    CONDITION_ONLINE[f"late100_s{k}_repetitive_delay3"][0], "delay3", FADE_DELAY3)
    for k in range(1, 6)}


# the planner's hand (EnvConfig.follow_plan, online_correction.py --follow-plan): an episode
# whose whole plan the arm can follow hands its joint goal over to the plan (the
# feedforward_plan rival's law), the others keep their controller: the hardware study alone and
# with its faded gated correction, and the feedforward rival with its faded correction (the
# plan-following rival with the rival's own correction where the plan cannot be followed).
# Test seeds 0-999: each the FADED set of the same name with the hand (and on the collision-aware
# IK, the plan its collision-aware path, every handed-over goal through the damper)
PLANNED = {
    **{f"late100_s{k}_plan": Variant("policy", f"seeds/{LATE100}_s{k}", None, None, plan=True)
       for k in range(1, 6)},
    **{f"{faded}_plan": variant._replace(plan=True) for faded, variant in FADED.items()},
    # ... and the same fine-tune trained with the hand in the loop (its env holds it: the hand
    # is on whether or not the flag is given), alone and with the hardware study's correction
    # setting, gated and faded in as above: the like-for-like pair of the two rows above
    **{f"late100hand_s{k}_plan": Variant("policy", f"seeds/{LATE100_HAND}_s{k}", None, None,
                                         plan=True) for k in range(1, 6)},
    **{f"late100hand_s{k}_repetitive_guarded_fade_plan": FADED[
        f"late100_s{k}_repetitive_guarded_fade"]._replace(
            model=f"seeds/{LATE100_HAND}_s{k}",
            spec=("policy", f"seeds/{LATE100_HAND}_s{k}", *ONLINE_HARDWARE), plan=True)
       for k in range(1, 6)}}


# ... and the ILC oracle restarted from each seed's stack (gated correction faded in, the hand
# on: online_correction.py play --oracle --follow-plan; test seeds 0-199), whose every replay
# runs with the hand too: the ceiling of the lead where the plan does not hold the arm; on the
# plain IK and on the collision-aware one (--clearance: the stack for a real arm)
# (prefix -> the PLANNED set it starts from)
PLANNED_ORACLES = {f"ilc_late100_s{k}_repetitive_guarded{ik}_fade_plan":
                   f"late100_s{k}_repetitive_guarded{ik}_fade_plan"
                   for ik in ("", "_clear") for k in range(1, 6)}
# ... and from the same stacks without the hand (FADED): how far each start's ceiling moves
# when the plan holds the arm, and how close the stack with the hand comes to the one without
FADED_ORACLES = {f"ilc_late100_s{k}_repetitive_guarded_fade":
                 f"late100_s{k}_repetitive_guarded_fade" for k in range(1, 6)}


# ... and the hand through 3 steps of latency and under 1 cm of noise (online_correction.py
# --condition with --follow-plan; named _hand: noise1_plan is a condition's name): the study's
# and the rival's corrected sets of those conditions, each as registered there, the plan taking
# what the arm can follow (prefix -> (spec, condition, gate))
PLANNED_CONDITION = {
    **{f"late100_s{k}_repetitive_delay3_hand": (*CONDITION_ONLINE[f"late100_s{k}_repetitive_delay3"],
                                                None) for k in range(1, 6)},
    **{f"late100_s{k}_repetitive_guarded_noise1_plan_hand": (
        *GATED[f"late100_s{k}_repetitive_guarded_noise1_plan"], GATE) for k in range(1, 6)},
    "feedforward_repetitive_delay3_hand": (*CONDITION_ONLINE["feedforward_repetitive_delay3"],
                                           None),
    "feedforward_repetitive_noise1_hand": (*CONDITION_ONLINE["feedforward_repetitive_noise1"],
                                           None)}


def online_prefixes() -> set[str]:
    """Every rollout set the online corrections' tables may read that prepare plays: the
    baselines, the archived policies' sets, the oracles, and each online registry's."""
    registries = (ONLINE, ONLINE_PLAIN, LOOPED_SEEDS, CONDITION_PLAIN, CONDITION_ONLINE, GATED,
                  ONLINE_ORACLES, GATED_ORACLES, ORACLES, BASELINES, LONG_EPISODES, CLEARANCE,
                  FADED, FADED_CONDITION, PLANNED, PLANNED_CONDITION, PLANNED_ORACLES,
                  FADED_ORACLES)
    return ({p for registry in registries for p in registry} | set(POLICY_SETS)
            | set(SEED_POLICY_SETS))


def _condition_flags(condition: str) -> list[str]:
    """eval.py's --env flags for one of studies/deploy.py's conditions (or its _plan variant:
    online_correction.condition_overrides)."""
    from online_correction import condition_overrides

    flags = []
    for key, value in (condition_overrides(condition) or {}).items():
        flags.append(f"--env.{key.replace('_', '-')}")
        flags += ([x for k, v in value.items() for x in (k, str(v))] if isinstance(value, dict)
                  else [str(value)])
    return flags


def _in_condition(meta: dict, condition: str, base: str = "policy") -> bool:
    """Whether a set's first rollout was played under exactly this condition's settings for its
    base (the ideal world's "none": no delay, no noise)."""
    from online_correction import condition_overrides

    env = meta.get("env") or {}
    want = condition_overrides(condition, base) or {"obs_delay": 0, "obs_noise": {}}
    return all(env.get(k, {} if k == "obs_noise" else 0) == v for k, v in want.items())


def _other_setting(setting: dict, spec: tuple, gate: float | None,
                   fade: float | None = None) -> bool:
    """Whether a set's recorded correction (its meta's "online", or an oracle's start) is not
    ``spec``'s setting with ``gate`` and ``fade`` (None: none recorded)."""
    return (tuple(setting.get(k) for k in SETTINGS) != spec[2:]
            or setting.get("max_error") != gate or setting.get("fade") != fade)


def _play_online(root: Path, spec: tuple, seeds: str, prefix: str, *extra: str,
                 gate: float | None = None, fade: float | None = None) -> None:
    base, model, kind, gain, advance, smooth = spec
    extra += ("--max-error", str(gate)) if gate else ()
    extra += ("--fade", str(fade)) if fade else ()
    with_model = ["--model", f"archive/{model}.zip"] if model else []
    _run(root, "studies/online_correction.py", "play", "--base", base, *with_model, "--kind",
         kind, "--gain", str(gain), "--advance", str(advance), "--smooth", str(smooth),
         "--seeds", seeds, "--prefix", prefix, *extra, "--force")


def _first_meta(root: Path, prefix: str) -> dict:
    from panda_lead.rollout import read_meta

    files = sorted((root / "rollouts" / prefix).glob("seed_*.npz"))
    return read_meta(files[0]) if files else {}


def _online_sets(root: Path, wanted=lambda prefix: True) -> None:
    """Each online set and oracle (re)played when missing, or played by another model or
    setting than ONLINE says (of those ``wanted``)."""
    for prefix, model in {**ONLINE_PLAIN, **LOOPED_SEEDS}.items():
        if not wanted(prefix):
            continue
        want = _archived_sha(root, model)
        if want and _set_model(root, prefix) != want:
            _run(root, "eval.py", "--seeds", "0-999", "--prefix", prefix, "--model",
                 f"archive/{model}.zip", "--force")
    for prefix, (model, condition) in CONDITION_PLAIN.items():
        if not wanted(prefix):
            continue
        want = _archived_sha(root, model)
        if want and (_set_model(root, prefix) != want
                     or not _in_condition(_first_meta(root, prefix), condition)):
            _run(root, "eval.py", "--seeds", "0-999", "--prefix", prefix, "--model",
                 f"archive/{model}.zip", *_condition_flags(condition), "--force")
    played = {**{p: (spec, "none", None, None, False) for p, spec in ONLINE.items()},
              **{p: (spec, c, None, None, False) for p, (spec, c) in CONDITION_ONLINE.items()},
              **{p: (spec, c, GATE, None, False) for p, (spec, c) in GATED.items()},
              **{p: (spec, c, None, fade, False)
                 for p, (spec, c, fade) in FADED_CONDITION.items()},
              **{p: (spec, c, gate, None, True)
                 for p, (spec, c, gate) in PLANNED_CONDITION.items()}}
    for prefix, (spec, condition, gate, fade, plan) in played.items():
        if not wanted(prefix):
            continue
        meta, model = _first_meta(root, prefix), spec[1]
        if (_other_setting(meta.get("online") or {}, spec, gate, fade)
                or not _in_condition(meta, condition, spec[0])
                or bool((meta.get("env") or {}).get("follow_plan", False)) != plan
                or (model and meta.get("model_sha256") != _archived_sha(root, model))):
            hand = ("--follow-plan",) if plan else ()
            _play_online(root, spec, "0-999", prefix, "--condition", condition, *hand,
                         gate=gate, fade=fade)
    _variant_sets(root, wanted, LONG_EPISODES, LONG_SEEDS, LONG_S)
    _variant_sets(root, wanted, CLEARANCE, "0-999")
    _variant_sets(root, wanted, FADED, "0-999")
    _variant_sets(root, wanted, PLANNED, "0-999")
    oracles = {**{p: Variant("policy", ONLINE[start][1], ONLINE[start], None)
                  for p, start in ONLINE_ORACLES.items()},
               **{p: Variant("policy", GATED[start][0][1], GATED[start][0], GATE)
                  for p, start in GATED_ORACLES.items()},
               **{p: PLANNED[start] for p, start in PLANNED_ORACLES.items()},
               **{p: FADED[start] for p, start in FADED_ORACLES.items()}}
    for prefix, start in oracles.items():  # (each the Variant of the set it starts from)
        if not wanted(prefix):
            continue
        ilc = _first_meta(root, prefix).get("ilc") or {}
        if (_other_setting(ilc.get("start_online") or {}, start.spec, start.gate, start.fade)
                or bool(ilc.get("start_follow_plan", False)) != start.plan
                or float(ilc.get("start_clearance", 0.0)) != start.clearance
                or ilc.get("start_model_sha256") != _archived_sha(root, start.spec[1])):
            aware = ("--follow-plan",) if start.plan else ()
            aware += ("--clearance", str(start.clearance)) if start.clearance else ()
            _play_online(root, start.spec, "0-199", prefix, "--oracle", *aware, gate=start.gate,
                         fade=start.fade)


def _variant_sets(root: Path, wanted, registry: dict, seeds: str, duration: float = 5.0) -> None:
    """A registry's sets (LONG_EPISODES, CLEARANCE, FADED, PLANNED: prefix -> Variant)
    (re)played when missing, or played at another length or clearance, by another model or
    with another setting."""
    for prefix, (base, model, spec, gate, clearance, fade, plan) in registry.items():
        if not wanted(prefix):
            continue
        meta = _first_meta(root, prefix)
        env = meta.get("env") or {}
        stale = (meta.get("duration") != duration
                 or (env.get("ik") or {}).get("clearance") != clearance
                 or bool(env.get("follow_plan", False)) != plan
                 or (spec and _other_setting(meta.get("online") or {}, spec, gate, fade))
                 or (model and meta.get("model_sha256") != _archived_sha(root, model)))
        if not stale:
            continue
        length = ("--duration", str(duration)) if duration != 5.0 else ()
        if spec:
            aware = ("--clearance", str(clearance)) if clearance else ()
            aware += ("--follow-plan",) if plan else ()
            _play_online(root, spec, seeds, prefix, *length, *aware, gate=gate, fade=fade)
            continue
        aware = ("--env.ik.clearance", str(clearance)) if clearance else ()
        aware += ("--env.follow-plan", "True") if plan else ()
        if base == "policy":
            _run(root, "eval.py", "--seeds", seeds, "--prefix", prefix, "--model",
                 f"archive/{model}.zip", *length, *aware, "--force")
        else:
            _run(root, "ikpd.py", "--controller", base, "--seeds", seeds, "--prefix", prefix,
                 *length, *aware, "--force")


def _baselines_missing(root: Path) -> bool:
    """Whether results/runs/baselines.json is absent or lacks one of runs.BASELINES (a rival
    added later)."""
    from runs import BASELINES as NAMES

    path = root / "results/runs/baselines.json"
    return not path.exists() or not set(NAMES) <= set(json.loads(path.read_text()))


def _run(root: Path, *argv: str) -> None:
    """Run one of the repo's scripts; if it fails (its own message printed above: a set
    another run is playing, a missing model), stop with one line naming it."""
    from panda_lead.errors import UserError

    print("run: uv run " + " ".join(argv), flush=True)
    rc = subprocess.run([sys.executable, *argv], cwd=root).returncode
    if rc:
        raise UserError(f"preparing the tables' inputs: `uv run {' '.join(argv[:3])} ...` "
                        f"exited {rc} (its message is above)")


def _set_model(root: Path, prefix: str) -> str | None:
    """The model_sha256 a rollout set's first file records (None: no set, or no model)."""
    meta = _first_meta(root, prefix)
    return (meta.get("ilc") or {}).get("start_model_sha256") or meta.get("model_sha256")


def _archived_sha(root: Path, name: str) -> str | None:
    side = root / "archive" / f"{name}.json"
    return json.loads(side.read_text()).get("model_sha256") if side.exists() else None


def prepare(root: Path, needed: set[str] | None = None) -> None:
    """Refresh what the tables read: the sweeps' summaries and chosen models, then every
    registered rollout set that is missing or played by another model or setting. With
    ``needed`` (results.py --only: the rollout sets the selected steps read), only those sets,
    and no sweep."""
    def wanted(prefix: str) -> bool:
        return needed is None or prefix in needed

    if needed is None:
        _sweeps(root)
    for base, extra in BASELINES.items():
        if wanted(base) and not (root / "rollouts" / base).is_dir():
            _run(root, "ikpd.py", "--seeds", "0-999", "--prefix", base, *extra)
    for m in [*POLICY_SETS, *(f"seeds/{m}" for m in SEED_POLICY_SETS)]:
        prefix = m.removeprefix("seeds/")
        want = _archived_sha(root, m) if wanted(prefix) else None
        if want and _set_model(root, prefix) != want:
            _run(root, "eval.py", "--seeds", "0-999", "--prefix", prefix, "--model",
                 f"archive/{m}.zip", "--force")
    _online_sets(root, wanted)
    # the oracles: 20 replays per trajectory, started from a model's lead, seeds 0-199
    for prefix, model in ORACLES.items():
        want = _archived_sha(root, model) if wanted(prefix) else None
        if want and _set_model(root, prefix) != want:
            _run(root, "ikpd.py", "--controller", "ilc", "--seeds", "0-199", "--prefix", prefix,
                 "--model", f"archive/{model}.zip", "--force")


def _sweeps(root: Path) -> None:
    """Each sweep's finished runs summarized, its chosen model archived (when missing), its
    kept seeds recorded."""
    runs = ["studies/runs.py"]
    for study in SUMMARIZED:
        for folder in [study, *EXTRA_SEEDS.get(study, [])]:
            found = sorted(glob.glob(f"sweeps/{folder}/runs/*/", root_dir=root))
            unfinished = [f for f in found if not (root / f / "final_model.zip").is_file()]
            for f in unfinished:  # a stopped sweep trial: summarize refuses the whole list
                print(f"skip: {f} is not a finished run (no final_model.zip)", flush=True)
            found = [f for f in found if f not in unfinished]
            if found:
                _run(root, *runs, "summarize", "--study", study, "--runs", *found)
    if _baselines_missing(root):
        _run(root, *runs, "baselines")  # computes only the ones the file lacks
    for name, (study, folders) in CHOSEN.items():
        dirs = [f"sweeps/{f}/runs" for f in folders if (root / f"sweeps/{f}/runs").is_dir()]
        if not (root / f"archive/{name}.zip").exists() and dirs:
            rule = ["--by", "selection"] if study in BY_SELECTION else []
            _run(root, *runs, "choose", "--study", study, *rule, "--archive-as", name, "--runs",
                 *dirs)
    for study, pattern in KEPT.items():
        dirs = sorted(glob.glob(f"sweeps/{pattern}/runs", root_dir=root))
        if dirs:
            _run(root, *runs, "keep", "--study", study, "--runs", *dirs)
