"""The results steps of the online corrections on top of a lead (issue 37, "a lead of another
kind"; docs/questions.md 9): studies/online_correction.py's tables over the rollout sets
studies/results_prepare.py plays, in the order results.py builds them. Split from
results_steps.py to keep each file readable in one sitting; table_steps calls online_steps."""

from __future__ import annotations

from results_steps import (
    HARDWARE,
    HEADLINE,
    LATE100_HAND,
    Step,
    _compare,
    _oracle_table,
    _pair,
    _report,
    _summary,
)


def _groups_step(out: str, command: str, groups: dict[str, list[str]], *extra: str) -> Step:
    """One of online_correction.py's group commands (excursions, limits) over labelled groups
    of rollout sets, its stdout the table ``out``."""
    return Step((out,), ("studies/online_correction.py", command, "--groups",
                         *(f"{label}={','.join(sets)}" for label, sets in groups.items()), *extra),
                tuple(f"rollouts/{x}" for sets in groups.values() for x in sets), stdout=True,
                section="all")


def online_steps() -> list[Step]:
    steps: list[Step] = []
    # online corrections on top of a lead (issue 37, "a lead of another kind"): the lap-to-lap
    # correction on the headline and on the analytic lead (both know each path's lap time),
    # and on each of the headline study's five seeds
    on = "results/studies/online"
    steps += [_pair(HEADLINE, "headline_repetitive", f"{on}/headline_repetitive_vs_headline.md"),
              # against its own oracle: the ILC restarted from the headline with the correction
              _oracle_table(f"{on}/headline_repetitive_with_oracle.md", "headline_repetitive",
                            "ilc_headline_repetitive"),
              _pair("analytic", "analytic_repetitive", f"{on}/analytic_repetitive_vs_analytic.md"),
              _pair("analytic_repetitive", "headline_repetitive",
                    f"{on}/headline_repetitive_vs_analytic_repetitive.md")]
    # ... and on the hardware model (its own tuning: its arm filter lags), against its own oracle
    hw = HARDWARE
    steps += [_pair(hw, "hardware_repetitive", f"{on}/hardware_repetitive_vs_hardware.md"),
              _oracle_table(f"{on}/hardware_repetitive_with_oracle.md", "hardware_repetitive",
                            "ilc_hardware_repetitive")]
    # the strongest classical rival with the same knowledge: the model-based feedforward with
    # its own lap-to-lap correction (tuning_feedforward.md)
    steps += [_pair("feedforward", "feedforward_repetitive",
                    f"{on}/feedforward_repetitive_vs_feedforward.md"),
              _pair("analytic_repetitive", "feedforward_repetitive",
                    f"{on}/feedforward_repetitive_vs_analytic_repetitive.md"),
              *(_pair("feedforward_repetitive", f"{lead}_repetitive",
                      f"{on}/{lead}_repetitive_vs_feedforward_repetitive.md")
                for lead in ("headline", "hardware"))]  # the archived models, by shape
    for study, name in (("kept", "learned lead + correction"),  # the headline's five seeds,
                        ("late100", "hardware lead + correction"),  # the hardware model's,
                        ("residual", "learned residual on it + correction")):  # and on the rival
        steps.append(_summary(f"{on}/{study}_repetitive_vs_feedforward_repetitive.md",
                              [("feedforward_repetitive", f"{study}_s{k}_repetitive")
                               for k in range(1, 6)], ("feedforward + correction", name)))
    for study in ("kept", "late100", "residual"):  # the same five-seed studies, each with
        # and without its correction
        steps.append(_summary(f"{on}/{study}_repetitive.md",
                              [(f"{study}_s{k}", f"{study}_s{k}_repetitive") for k in range(1, 6)],
                              paired=True))
    # ... under studies/deploy.py's conditions (latency d: the lead's channel d steps late each
    # way; noise1: every reading noisy, the correction reading the measured error): the hardware
    # study's correction against its seeds alone and against itself in the ideal world, and
    # through latency against the feedforward rival's correction under the same latency
    late100 = [f"late100_s{k}" for k in range(1, 6)]
    # (under noise the rival's IK aims at the plan: one rival for both noise worlds)
    rival = {"noise1_plan": "noise1"}
    for cond, named in (("delay1", "latency 1"), ("delay3", "latency 3"), ("noise1", "noise 1 cm"),
                        ("noise1_plan", "noise 1 cm, IK on the plan")):
        tables = {
            f"late100_repetitive_{cond}": ([(f"{p}_{cond}", f"{p}_repetitive_{cond}")
                                            for p in late100], ("alone", "with the correction"),
                                           True),
            f"late100_repetitive_{cond}_vs_late100_repetitive": (
                [(f"{p}_repetitive", f"{p}_repetitive_{cond}") for p in late100],
                ("ideal world", named), True)}
        ff = f"feedforward_repetitive_{rival.get(cond, cond)}"
        tables[f"late100_repetitive_{cond}_vs_{ff}"] = (
            [(ff, f"{p}_repetitive_{cond}") for p in late100],
            ("feedforward + correction", "hardware lead + correction"), False)
        if cond not in rival:
            steps.append(_pair("feedforward", ff, f"{on}/{ff}_vs_feedforward.md"))
        steps += [_summary(f"{on}/{name}.md", sets, names, paired)
                  for name, (sets, names, paired) in tables.items()]
    # what a mean hides: the rare large excursions and self-collisions, with and without it
    groups, sets = [], []
    worlds = {"": "", "_delay3": ", delay3", "_noise1": ", noise1",
              "_noise1_plan": ", noise1, IK on the plan"}
    for cond, world in worlds.items():
        for label, mid in (("alone", ""), ("with its correction", "_repetitive")):
            prefixes = [f"{p}{mid}{cond}" for p in late100]
            groups.append(f"hardware study {label}{world}={','.join(prefixes)}")
            sets += prefixes
    steps.append(_oracle_table(f"{on}/hardware_repetitive_guarded_with_oracle.md",
                               "hardware_repetitive_guarded", "ilc_hardware_repetitive_guarded"))
    for cond, world in worlds.items():  # not learning from errors farther than 5 cm
        gated = [f"{p}_repetitive_guarded{cond}" for p in late100]
        groups.append(f"hardware study with its correction gated at 5 cm{world}="
                      f"{','.join(gated)}")
        sets += gated
    groups += ["feedforward alone=feedforward", "feedforward with its correction="
               "feedforward_repetitive", "feedforward with its correction, noise1="
               "feedforward_repetitive_noise1"]
    for name, side_a, names in (("late100_repetitive_guarded", "{p}", ("alone", "gated")),
                                ("late100_repetitive_guarded_vs_ungated", "{p}_repetitive",
                                 ("ungated", "gated at 5 cm")),
                                ("late100_repetitive_guarded_delay3_vs_ungated",
                                 "{p}_repetitive_delay3", ("ungated, latency 3", "gated")),
                                ("late100_repetitive_guarded_noise1_vs_ungated",
                                 "{p}_repetitive_noise1", ("ungated, noise 1 cm", "gated")),
                                ("late100_repetitive_guarded_noise1_plan_vs_ungated",
                                 "{p}_repetitive_noise1_plan",
                                 ("ungated, noise 1 cm, IK on the plan", "gated"))):
        cond = name.removeprefix("late100_repetitive_guarded").removesuffix("_vs_ungated")
        steps.append(_summary(f"{on}/{name}.md", [(side_a.format(p=p),
                                                   f"{p}_repetitive_guarded{cond}")
                                                  for p in late100], names, paired=True))
    # ... and the gated study against the strongest rival with its own correction, ungated: the
    # gate was offered to the rival too and hurt it on the selection seeds (tuning_gate.md)
    for cond in ("", "_noise1", "_noise1_plan"):  # (under noise, the gate chosen without it)
        ff = f"feedforward_repetitive{cond.removesuffix('_plan')}"
        steps.append(_summary(
            f"{on}/late100_repetitive_guarded{cond}_vs_{ff}.md",
            [(ff, f"{p}_repetitive_guarded{cond}") for p in late100],
            ("feedforward + correction", "hardware lead + gated correction")))
    # the picture of it: settled error against jerk, the rival and the hardware study with and
    # without their corrections, in the ideal world and under noise with both IKs on the plan
    # (the rival alone is immune to noise: one point)
    ideal, noisy = "ideal world", "noise 1 cm, IK on the plan"
    figure_groups = {"feedforward (model-based rival; immune to noise)": [(ideal, "feedforward")],
                     "feedforward + correction": [(ideal, "feedforward_repetitive"),
                                                  (noisy, "feedforward_repetitive_noise1")]}
    for name, mid in (("hardware study", ""), ("hardware study + correction", "_repetitive"),
                      ("hardware study + gated correction", "_repetitive_guarded")):
        figure_groups[name] = [(world, ",".join(f"{p}{mid}{cond}" for p in late100))
                               for world, cond in ((ideal, ""), (noisy, "_noise1_plan"))]
    # ... and the two corrected controllers on the collision-aware IK (results_prepare.CLEARANCE)
    # (first in each list, so that a controller's line runs collision-aware -> ideal -> noise)
    off_itself = "ideal world, collision-aware IK"
    figure_groups["feedforward + correction"].insert(0, (off_itself,
                                                        "feedforward_repetitive_clear"))
    figure_groups["hardware study + gated correction"].insert(
        0, (off_itself, ",".join(f"{p}_repetitive_guarded_clear" for p in late100)))
    # ... and with the planner's hand (results_prepare.PLANNED, PLANNED_CONDITION; the ideal
    # and collision-aware corrections faded in, the noise ones as registered there)
    figure_groups["feedforward that follows its plan"] = [(ideal, "feedforward_plan")]
    figure_groups["feedforward + correction + planner's hand"] = [
        (off_itself, "feedforward_repetitive_clear_fade_plan"),
        (ideal, "feedforward_repetitive_fade_plan"), (noisy, "feedforward_repetitive_noise1_hand")]
    figure_groups["hardware study + gated correction + planner's hand"] = [
        (world, ",".join(f"{p}_repetitive_guarded{mid}" for p in late100))
        for world, mid in ((off_itself, "_clear_fade_plan"), (ideal, "_fade_plan"),
                           (noisy, "_noise1_plan_hand"))]
    groups_argv = [f"{name} @ {world}={sets}" for name, worlds in figure_groups.items()
                   for world, sets in worlds]
    read = [s for worlds in figure_groups.values() for _, sets in worlds for s in sets.split(",")]
    steps.append(Step((f"{on}/planned_path.png",),
                      ("studies/online_correction.py", "figure", "--groups", *groups_argv,
                       "--out", "{out0}"),
                      tuple(f"rollouts/{x}" for x in dict.fromkeys(read)), section="all"))
    # what the laps would buy: 10 s episodes, settled from 5 s (the second half), test seeds
    # 0-199: each correction against its lead alone, and the two corrections against each other
    late = ("--settle-time", "5")
    steps += [_pair("hardware_10s", "hardware_repetitive_guarded_10s",
                    f"{on}/ten_seconds_hardware_gated_vs_alone.md", *late),
              _pair("feedforward_10s", "feedforward_repetitive_10s",
                    f"{on}/ten_seconds_feedforward_repetitive_vs_alone.md", *late),
              _pair("feedforward_repetitive_10s", "hardware_repetitive_guarded_10s",
                    f"{on}/ten_seconds_hardware_gated_vs_feedforward_repetitive.md", *late)]
    # where in the episode the gain comes, per shape: 0.5 s windows of the study's seed 1 alone
    # and gated beside the oracle (5 s, test seeds 0-199), and of the 10 s sets
    for out, shown in (("windows", ["seed 1 alone=late100_s1",
                                     "seed 1 gated=late100_s1_repetitive_guarded",
                                     "oracle, from the archived model gated="
                                     "ilc_hardware_repetitive_guarded"]),
                        ("ten_seconds_windows", [
                            "archived model alone=hardware_10s",
                            "archived model gated=hardware_repetitive_guarded_10s",
                            "feedforward alone=feedforward_10s",
                            "feedforward + correction=feedforward_repetitive_10s"])):
        steps.append(Step((f"{on}/{out}.md",),
                          ("studies/online_correction.py", "windows", "--groups", *shown),
                          tuple(f"rollouts/{g.split('=')[1]}" for g in shown), stdout=True,
                          section="all"))
    # ... and the hardware study's five seeds: gated against alone, and against the rival
    study = ("--settle-time", "5")
    steps += [_summary(f"{on}/ten_seconds_late100_gated.md",
                       [(f"{p}_10s", f"{p}_repetitive_guarded_10s") for p in late100],
                       ("alone", "gated"), paired=True, extra=study),
              _summary(f"{on}/ten_seconds_late100_gated_vs_feedforward_repetitive.md",
                       [("feedforward_repetitive_10s", f"{p}_repetitive_guarded_10s")
                        for p in late100],
                       ("feedforward + correction", "hardware lead + gated correction"),
                       extra=study)]
    steps.append(Step((f"{on}/excursions.md",),
                      ("studies/online_correction.py", "excursions", "--groups", *groups),
                      tuple(f"rollouts/{x}" for x in (*sets, "feedforward",
                                                      "feedforward_repetitive",
                                                      "feedforward_repetitive_noise1")),
                      stdout=True, section="all"))
    # a real arm stops when it touches itself: the collision-aware IK under the study (alone and
    # gated) and under the rival (alone and with its correction), each its own clearance
    # (results_prepare.CLEARANCE, tuning_clearance.md): what it costs each, and the two again
    shown = {"hardware study alone": late100,
             "hardware study alone, collision-aware": [f"{p}_clear" for p in late100],
             "hardware study, gated correction": [f"{p}_repetitive_guarded" for p in late100],
             "hardware study, gated correction, collision-aware": [
                 f"{p}_repetitive_guarded_clear" for p in late100],
             "feedforward alone": ["feedforward"],
             "feedforward with its correction": ["feedforward_repetitive"],
             "feedforward alone, collision-aware": ["feedforward_clear"],
             "feedforward with its correction, collision-aware": ["feedforward_repetitive_clear"]}
    steps.append(_groups_step(f"{on}/excursions_clearance.md", "excursions", shown))
    # ... and would a real Panda accept them (the deploy check on the same sets, the analytic
    # lead beside them)
    # (against the analytic lead: issue 36's acceptance target; against the study alone: what
    # the correction costs there)
    judged = {"analytic lead": ["analytic"], **shown}
    for out, against in (("limits_clearance", "analytic lead"),
                         ("limits_clearance_vs_alone", "hardware study alone")):
        steps.append(_groups_step(f"{on}/{out}.md", "limits", judged, "--against", against))
    # ... and through 3 steps of latency, the correction (ungated there) against the study alone
    latency = {"alone, latency 3": [f"{p}_delay3" for p in late100],
               "with its correction, latency 3": [f"{p}_repetitive_delay3" for p in late100]}
    steps.append(_groups_step(f"{on}/limits_delay3.md", "limits", latency, "--against",
                              "alone, latency 3"))
    # ... and the corrections faded in (results_prepare.FADED, tuning_fade.md): what the Panda
    # accepts then (against the study alone and against the analytic lead), what the fade costs,
    # and the faded controllers against each other and against the lead alone
    faded = {"hardware study, gated correction faded in": [
                 f"{p}_repetitive_guarded_fade" for p in late100],
             "hardware study, gated correction faded in, collision-aware": [
                 f"{p}_repetitive_guarded_clear_fade" for p in late100],
             "feedforward with its correction faded in": ["feedforward_repetitive_fade"],
             "feedforward with its correction faded in, collision-aware": [
                 "feedforward_repetitive_clear_fade"]}
    judged = {**judged, **faded}
    for out, against in (("limits_fade", "hardware study alone"),
                         ("limits_fade_vs_analytic", "analytic lead")):
        steps.append(_groups_step(f"{on}/{out}.md", "limits", judged, "--against", against))
    steps.append(_groups_step(f"{on}/excursions_fade.md", "excursions", faded))
    # ... and where the controllers' acceptance differs: per shape, the classical controller (the
    # paths' own demands) beside the leads and the rival
    by_shape = {"classical (no lead)": ["classical"], "analytic lead": ["analytic"],
                "hardware study alone": late100,
                "hardware study, gated correction faded in, collision-aware":
                    faded["hardware study, gated correction faded in, collision-aware"],
                "feedforward alone": ["feedforward"],
                "feedforward with its correction faded in, collision-aware":
                    ["feedforward_repetitive_clear_fade"]}
    steps.append(_groups_step(f"{on}/limits_by_shape.md", "limits", by_shape, "--by-shape"))
    # ... and, episode by episode, where each loss comes from: the correction switched on at once
    # against the study alone (ideal world and latency 3), and the study alone against the rival
    lost = {"lost_to_correction": {"hardware study alone": late100,
                                   "gated correction, at once": [f"{p}_repetitive_guarded"
                                                                 for p in late100]},
            "lost_to_correction_delay3": latency,
            "lost_to_rival": {"feedforward alone": ["feedforward"],
                              "hardware study alone": late100}}
    steps += [_groups_step(f"{on}/{out}.md", "limits", groups, "--lost-against", next(iter(groups)))
              for out, groups in lost.items()]
    # ... through 3 steps of latency, faded in over 0.2 s (results_prepare.FADED_CONDITION: the
    # trade tuning_fade.md shows, not its rule's choice)
    latency_faded = {**latency, "with its correction faded in over 0.2 s, latency 3": [
        f"{p}_repetitive_delay3_fade" for p in late100]}
    steps += [_groups_step(f"{on}/limits_delay3_fade.md", "limits", latency_faded, "--against",
                           "alone, latency 3"),
              _summary(f"{on}/late100_repetitive_delay3_fade_vs_at_once.md",
                       [(f"{p}_repetitive_delay3", f"{p}_repetitive_delay3_fade")
                        for p in late100], ("switched on at once", "faded in over 0.2 s"),
                       paired=True)]
    steps += [_summary(f"{on}/late100_repetitive_guarded_fade_vs_guarded.md",
                       [(f"{p}_repetitive_guarded", f"{p}_repetitive_guarded_fade")
                        for p in late100], ("switched on at once", "faded in"), paired=True),
              _summary(f"{on}/late100_repetitive_guarded_clear_fade_vs_alone_clear.md",
                       [(f"{p}_clear", f"{p}_repetitive_guarded_clear_fade") for p in late100],
                       ("alone, collision-aware", "gated correction faded in, collision-aware"),
                       paired=True),
              _pair("feedforward_repetitive", "feedforward_repetitive_fade",
                    f"{on}/feedforward_repetitive_fade_vs_feedforward_repetitive.md"),
              _summary(f"{on}/late100_repetitive_guarded_clear_fade_vs_feedforward_repetitive"
                       "_clear_fade.md",
                       [("feedforward_repetitive_clear_fade", f"{p}_repetitive_guarded_clear_fade")
                        for p in late100],
                       ("feedforward + correction faded in, collision-aware",
                        "hardware lead + gated correction faded in, collision-aware"))]
    steps += [_summary(f"{on}/late100_clear_vs_alone.md",
                       [(p, f"{p}_clear") for p in late100], ("plain IK", "collision-aware IK"),
                       paired=True),
              _summary(f"{on}/late100_repetitive_guarded_clear_vs_guarded.md",
                       [(f"{p}_repetitive_guarded", f"{p}_repetitive_guarded_clear")
                        for p in late100], ("plain IK", "collision-aware IK"), paired=True),
              _pair("feedforward_repetitive", "feedforward_repetitive_clear",
                    f"{on}/feedforward_repetitive_clear_vs_feedforward_repetitive.md"),
              _pair("feedforward", "feedforward_clear", f"{on}/feedforward_clear_vs_feedforward.md"),
              _summary(f"{on}/late100_repetitive_guarded_clear_vs_feedforward_repetitive_clear.md",
                       [("feedforward_repetitive_clear", f"{p}_repetitive_guarded_clear")
                        for p in late100],
                       ("feedforward + correction, collision-aware",
                        "hardware lead + gated correction, collision-aware"))]
    # ... and the planner's hand (results_prepare.PLANNED; EnvConfig.follow_plan): each episode
    # whose whole plan the arm can follow handed over to the plan, the rest kept: what it adds to
    # the study alone and with its correction, the learned stack with it against the rival with
    # it, and what the Panda's limits accept then
    planned = {"hardware study alone": late100,
               "hardware study, planner's hand": [f"{p}_plan" for p in late100],
               "hardware study, gated correction faded in": faded[
                   "hardware study, gated correction faded in"],
               "hardware study, gated correction faded in, planner's hand": [
                   f"{p}_repetitive_guarded_fade_plan" for p in late100],
               "feedforward that follows its plan": ["feedforward_plan"],
               "feedforward with its correction faded in, planner's hand": [
                   "feedforward_repetitive_fade_plan"]}
    steps += [_summary(f"{on}/late100_plan_vs_alone.md", [(p, f"{p}_plan") for p in late100],
                       ("alone", "planner's hand"), paired=True),
              _summary(f"{on}/late100_repetitive_guarded_fade_plan_vs_fade.md",
                       [(f"{p}_repetitive_guarded_fade", f"{p}_repetitive_guarded_fade_plan")
                        for p in late100], ("gated correction faded in", "the same, planner's hand"),
                       paired=True, extra=("--levels",)),
              _summary(f"{on}/late100_plan_vs_feedforward_plan.md",
                       [("feedforward_plan", f"{p}_plan") for p in late100],
                       ("feedforward that follows its plan", "hardware lead, planner's hand")),
              _summary(f"{on}/late100_repetitive_guarded_fade_plan_vs_feedforward_repetitive"
                       "_fade_plan.md",
                       [("feedforward_repetitive_fade_plan", f"{p}_repetitive_guarded_fade_plan")
                        for p in late100],
                       ("feedforward + correction faded in, planner's hand",
                        "hardware lead + gated correction faded in, planner's hand")),
              _groups_step(f"{on}/limits_plan.md", "limits", planned, "--against",
                           "hardware study, gated correction faded in"),
              _groups_step(f"{on}/excursions_plan.md", "excursions", planned)]
    # ... and the share of its own oracle's gain each seed's stack captures (the ILC restarted
    # from it, the hand on in every replay: results_prepare.PLANNED_ORACLES; test seeds 0-199),
    # and the study's over its five seeds (oracle_share.py); the same for the stacks without the
    # hand (FADED_ORACLES: whether the hand moves the ceiling it is measured against) and for
    # the stacks on the collision-aware IK (the stack for a real arm)
    for name, kind in (("hand", "fade_plan"), ("fade", "fade"), ("hand_clear", "clear_fade_plan")):
        steps += [_oracle_table(f"{on}/{name}_with_oracle_s{k}.md",
                                f"{p}_repetitive_guarded_{kind}",
                                f"ilc_{p}_repetitive_guarded_{kind}")
                  for k, p in enumerate(late100, start=1)]
        pairs = [(f"{p}_repetitive_guarded_{kind}", f"ilc_{p}_repetitive_guarded_{kind}")
                 for p in late100]
        steps.append(Step((f"{on}/{name}_with_oracle_study.md",),
                          ("studies/oracle_share.py", "--pairs", *(":".join(x) for x in pairs)),
                          ("rollouts/analytic", *(f"rollouts/{x}" for p in pairs for x in p)),
                          stdout=True, section="all"))
    # ... and the same fine-tune trained with the hand in the loop (results_steps.LATE100_HAND),
    # each seed against the seed of the same start trained without it, both played with the hand
    hand = [f"late100hand_s{k}" for k in range(1, 6)]
    trained = f"results/studies/{LATE100_HAND}"
    steps += [_summary(f"{trained}/vs_late100_plan.md",
                       [(f"{p}_plan", f"{h}_plan") for p, h in zip(late100, hand, strict=True)],
                       ("trained without the hand", "trained with it"), paired=True),
              _summary(f"{trained}/vs_late100_repetitive_guarded_fade_plan.md",
                       [(f"{p}_repetitive_guarded_fade_plan", f"{h}_repetitive_guarded_fade_plan")
                        for p, h in zip(late100, hand, strict=True)],
                       ("trained without the hand, correction faded in",
                        "trained with it, correction faded in"), paired=True,
                       extra=("--levels",)),
              _summary(f"{trained}/vs_feedforward_repetitive_fade_plan.md",
                       [("feedforward_repetitive_fade_plan", f"{h}_repetitive_guarded_fade_plan")
                        for h in hand],
                       ("feedforward + correction faded in, planner's hand",
                        "trained with the hand + gated correction faded in")),
              _groups_step(f"{trained}/limits.md", "limits", {
                  "trained without the hand, correction faded in, planner's hand": [
                      f"{p}_repetitive_guarded_fade_plan" for p in late100],
                  "trained with the hand, correction faded in, planner's hand": [
                      f"{h}_repetitive_guarded_fade_plan" for h in hand],
                  "feedforward with its correction faded in, planner's hand": [
                      "feedforward_repetitive_fade_plan"]}, "--against",
                  "trained without the hand, correction faded in, planner's hand")]
    # ... through 3 steps of latency and under 1 cm of noise (results_prepare.PLANNED_CONDITION):
    # the study with the hand against the rival with it
    steps += [_summary(f"{on}/late100_repetitive_delay3_hand_vs_feedforward_repetitive_delay3"
                       "_hand.md",
                       [("feedforward_repetitive_delay3_hand", f"{p}_repetitive_delay3_hand")
                        for p in late100],
                       ("feedforward + correction, latency 3, planner's hand",
                        "hardware lead + correction, latency 3, planner's hand")),
              _summary(f"{on}/late100_repetitive_guarded_noise1_plan_hand_vs_feedforward"
                       "_repetitive_noise1_hand.md",
                       [("feedforward_repetitive_noise1_hand",
                         f"{p}_repetitive_guarded_noise1_plan_hand") for p in late100],
                       ("feedforward + correction, noise 1 cm, planner's hand",
                        "hardware lead + gated correction, noise 1 cm, planner's hand"))]
    # ... the same on the collision-aware IK, the stack for a real arm
    aware = {"hardware study, gated correction faded in, collision-aware": faded[
                 "hardware study, gated correction faded in, collision-aware"],
             "the same, planner's hand": [f"{p}_repetitive_guarded_clear_fade_plan"
                                          for p in late100],
             "feedforward with its correction faded in, collision-aware": [
                 "feedforward_repetitive_clear_fade"],
             "the same, planner's hand (rival)": ["feedforward_repetitive_clear_fade_plan"]}
    steps += [_summary(f"{on}/late100_repetitive_guarded_clear_fade_plan_vs_clear_fade.md",
                       [(f"{p}_repetitive_guarded_clear_fade",
                         f"{p}_repetitive_guarded_clear_fade_plan") for p in late100],
                       ("gated correction faded in, collision-aware", "the same, planner's hand"),
                       paired=True, extra=("--levels",)),
              _summary(f"{on}/late100_repetitive_guarded_clear_fade_plan_vs_feedforward"
                       "_repetitive_clear_fade_plan.md",
                       [("feedforward_repetitive_clear_fade_plan",
                         f"{p}_repetitive_guarded_clear_fade_plan") for p in late100],
                       ("feedforward + correction faded in, collision-aware, planner's hand",
                        "hardware lead + gated correction faded in, collision-aware, planner's "
                        "hand")),
              _groups_step(f"{on}/limits_plan_clear.md", "limits", aware, "--against",
                           "hardware study, gated correction faded in, collision-aware"),
              _groups_step(f"{on}/excursions_plan_clear.md", "excursions", aware)]
    # ... and trained with it in the loop (EnvConfig.repetitive_gain): each seed against the same
    # seed's plain model with the correction added after training, and against its oracle
    looped = "v5_err_decay_repetitive_5m"
    pairs = {"looped_vs_added": ("kept_s{k}_repetitive", "looped_s{k}", "added after training",
                                 "trained with it"),
             "looped_vs_plain": ("kept_s{k}", "looped_s{k}", "plain", "trained with it"),
             "looped_finetuned_vs_added": ("kept_s{k}_repetitive", "looped_ft_s{k}",
                                           "added after training", "trained on with it"),
             "looped_finetuned_vs_control_added": ("finetuned_s{k}_repetitive", "looped_ft_s{k}",
                                                   "trained on without it, added after",
                                                   "trained on with it"),
             "looped_long_vs_added": ("long_s{k}_repetitive", "looped_long_s{k}",
                                      "added after training", "trained with it"),
             "looped_long_vs_looped": ("looped_s{k}", "looped_long_s{k}",
                                       "trained with it on 2 s episodes", "on 5 s episodes"),
             "long_added_vs_added": ("kept_s{k}_repetitive", "long_s{k}_repetitive",
                                     "added after training on 2 s episodes",
                                     "on 5 s episodes"),
             "looped_finetuned_vs_looped": ("looped_s{k}", "looped_ft_s{k}",
                                            "trained with it from scratch",
                                            "trained on with it")}
    # the pairs whose two sides grew from one model (the headline study's seed k): their CIs
    # may draw the seeds once for both sides as well (--paired-seeds)
    shared_origin = ("looped_finetuned_vs_added", "looped_finetuned_vs_control_added")
    for name, (side_a, side_b, a_name, b_name) in pairs.items():
        steps.append(_summary(f"{on}/{name}.md", [(side_a.format(k=k), side_b.format(k=k))
                                                  for k in range(1, 6)], (a_name, b_name),
                              paired=name in shared_origin))
    looped_obs = "v5_err_decay_repetitive_observed_5m"
    steps += [_report(looped_obs), _compare(looped_obs, looped)]  # (a two-seed pilot)
    long, looped_long = "v5_err_decay_long_5m", "v5_err_decay_repetitive_long_5m"
    steps += [_report(long), _compare(long, "v5_err_decay_kept"), _report(looped_long),
              _compare(looped_long, long), _compare(looped_long, looped)]
    looped_ft = "v5_err_decay_repetitive_finetuned_5m"
    steps += [_report(looped_ft), _compare(looped_ft, "v5_err_decay_finetuned_5m"),
              _compare(looped_ft, "v5_err_decay_kept"),
              _oracle_table(f"{on}/looped_finetuned_with_oracle.md", looped_ft, "ilc_looped_ft")]
    steps += [_report(looped), _compare(looped, "v5_err_decay_kept"),
              _pair("headline_repetitive", looped, f"{on}/looped_vs_headline_repetitive.md"),
              _oracle_table(f"{on}/looped_with_oracle.md", looped, "ilc_looped")]
    return steps
