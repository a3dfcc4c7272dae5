"""The probes behind docs/deploy.md's explanations (the tuning seeds, or with --on-selection N
the first N selection-set trajectories; never the test seeds):
what a low-pass does to the filtered rival, where the arm's limits bind on the paths near them,
how much of the limit term a lead could change, and how much of it a PPO policy's exploration
makes.

    uv run studies/deploy_probes.py rival-lowpass      # the rival with a low-pass on its lead
    uv run studies/deploy_probes.py margins --models \\
        archive/seeds/deploy_large_batch_continued_5m_s3.zip \\
        archive/seeds/deploy_large_batch_limit_continued_5m_s3.zip
    uv run studies/deploy_probes.py margins --conditions none delay1 --lead-filter-hz 0 40 25 15
    uv run studies/deploy_probes.py limit-excess   # the limit term's excess per 2 s episode
    uv run studies/deploy_probes.py limit-exploration  # limit_lead_only's term, with exploration
    uv run studies/deploy_probes.py lead-excess  # what a lead adds to a zero lead's, by condition
    uv run studies/deploy_probes.py lost-paths --models \\
        archive/deploy_large_batch_curv10_10m_lp10.zip --on-selection 300  # where the arm rejects
    uv run studies/deploy_probes.py stack-weights --models \\
        archive/seeds/deploy_large_batch_curv10_actions_stack8_continued_5m_s1.zip  # per input

Each prints a few lines; about a minute each on the 2-core AMD EPYC (stack-weights: seconds).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
from deploy import RIVALS, SKIP_S, _error_and_jerk, _play, accepted_by_arm, controllers_for, overrides

from panda_lead.errors import UserError, exit_on_user_error


@dataclass
class Args:
    probe: tyro.conf.Positional[Literal["rival-lowpass", "margins", "limit-excess",
                                        "limit-exploration", "lead-excess", "lost-paths",
                                        "stack-weights"]]
    """Which probe to run."""
    models: list[Path] = field(
        default_factory=lambda: [Path("archive/deploy_large_batch_10m.zip")])
    """margins: the models beside the analytic leads; limit-excess, limit-exploration,
    lead-excess: the first is played; stack-weights: the models whose weights are read."""
    conditions: list[str] = field(default_factory=lambda: ["delay1"])
    """margins: the conditions (studies/deploy.py's names)."""
    lead_filter_hz: list[float] = field(default_factory=lambda: [0.0])
    """margins: a low-pass on the models' lead (EnvConfig.lead_filter_hz), one pass per value."""
    on_selection: int = 0
    """Play the first N selection-set trajectories (seeds from 5,000,000: never trained, tuned
    or tested on) instead of the 50 tuning seeds; 0: the tuning seeds."""


def rival_lowpass(steps: int, seeds: list[int]) -> None:
    """The filtered analytic lead at 1 cm with lead_filter_hz on its lead: its lead carries the
    correction of the IK's aim from the noisy reading to the estimate, which the low-pass
    delays."""
    from panda_lead import controllers, harness

    for hz in (0.0, 20.0, 10.0, 5.0):
        base = harness.build("analytic", steps, None,
                             {**overrides("noise1"), "lead_filter_hz": hz})
        ctrl = harness.Controller("f", base.config, {}, controllers.make_filtered_analytic())
        err, jerk = _error_and_jerk(ctrl, seeds)
        print(f"filtered analytic lead, lead low-pass {hz:4.0f} Hz: mean error {err:.3f} cm, "
              f"jerk {jerk:.0f} m/s^3", flush=True)


def margins(args: Args, steps: int, seeds: list[int]) -> None:
    """Share accepted and the worst peak / limit of the paths near the limits (<= 2.2), beside
    the 100 Hz joint goals' own peak acceleration / limit (what the limit term measures)."""
    from panda_lead import harness
    from panda_lead.limits import JOINT_ACC

    for cond in args.conditions:
        for hz in args.lead_filter_hz:
            # without a low-pass: the baselines and the models; with one: the models alone
            ctrls = ({f"{p.stem} + {hz:g} Hz": harness.build(
                "policy", steps, p, {**overrides(cond), "lead_filter_hz": hz})
                for p in args.models} if hz else controllers_for(cond, args.models, steps))
            for name, ctrl in ctrls.items():
                rs = _play(ctrl, seeds)
                checks = accepted_by_arm(rs)
                worst = np.array([checks[s].worst_margin for s in seeds])
                acc = {s: (np.abs(np.diff(rs[s].q_goal, 2, axis=0)) / rs[s].dt ** 2
                           / JOINT_ACC)[int(SKIP_S / rs[s].dt):].max(axis=1) for s in seeds}
                peak = np.array([acc[s].max() for s in seeds])
                # when the 100 Hz peak comes (s; the second difference ending at that goal)
                when = [SKIP_S + (acc[s].argmax() + 2) * rs[s].dt for s in seeds]
                near = " ".join(f"{s}:{w:.2f}/{p:.2f}@{t:.2f}s" for s, w, p, t in
                                zip(seeds, worst, peak, when, strict=True) if w <= 2.2)
                print(f"{cond} {name}: accepted {100 * np.mean(worst <= 1):.0f}%, median worst "
                      f"peak/limit {np.median(worst):.2f}; near the limits (seed: 1 kHz / "
                      f"100 Hz @ its time): {near}", flush=True)


def limit_excess(args: Args, seeds: list[int]) -> None:
    """The w_limit term's clipped excess summed over a 2 s training-length episode from 0.5 s,
    for a trained lead (deterministic) under each condition."""
    from panda_lead import harness
    from panda_lead.limits import JOINT_ACC

    for cond in ("none", "delay1", "delay3", "noise1"):
        ctrl = harness.build("policy", 200, args.models[0], overrides(cond))
        rs = _play(ctrl, seeds)
        per = [np.clip(np.abs(np.diff(r.q_goal, 2, axis=0))[int(SKIP_S / r.dt) - 2:]
                       / r.dt ** 2 / JOINT_ACC - 1, 0, 1).sum() for r in rs.values()]
        print(f"{cond}: excess per episode median {np.median(per):.1f}, mean {np.mean(per):.1f}",
              flush=True)


def _limit_world(model: Path, w_limit: float, seeds: list[int]):
    """-> (the model's policy, its env as a fixed nominal world, 2 s episodes, with
    limit_lead_only's term at ``w_limit``, the seeds whose paths the term charges, and the
    model's own obs_noise, for the probes to put back)."""
    from panda_lead import trajectory
    from panda_lead.config import LIMIT_FEASIBLE_ACC, EnvConfig
    from panda_lead.models import load_policy

    policy, env, _ = load_policy(model)
    config = EnvConfig.from_dict(env)
    nominal = config.replace(
        w_limit=w_limit, limit_lead_only=True, episode_steps=200, random_delay=False,
        random_noise=False, nominal_share=0.0, obs_delay=0, action_delay=0, target_delay=0,
        obs_noise={})
    paths = [s for s in seeds if trajectory.sample(s).peak_acc <= LIMIT_FEASIBLE_ACC]
    return policy, nominal, paths, config.obs_noise


def limit_exploration(args: Args, seeds: list[int]) -> None:
    """limit_lead_only's term (w_limit 0.2, as deploy_large_batch_limit_lead_continued) summed
    over a 2 s episode of the nominal world on the paths it charges, for the first model's
    deterministic lead and with PPO's exploration added: a Gaussian of the given std (share of
    the lead's bound) drawn afresh each step, as the policy's std in training, or gSDE's
    (TrainConfig.use_sde): the policy's last hidden layer times a matrix drawn once per
    episode, its entries' std exp(log_std_init) (-3.7: ~0.08 of the bound here)."""
    import torch

    from panda_lead.task import LeadTask

    policy, config, paths, _ = _limit_world(args.models[0], 0.2, seeds)
    for kind, size in (("none", 0.0), ("white", 0.02), ("white", 0.082), ("gsde", -3.7)):
        task, rng = LeadTask(config, len(paths), nthread=2), np.random.default_rng(0)
        task.rngs = [np.random.default_rng(s) for s in paths]  # (as rollout.py seeds them)
        obs, limit, distance, stds = task.reset(None, paths), 0.0, 0.0, []
        matrix = np.exp(size) * rng.standard_normal((len(paths), 64, 3))
        for _ in range(config.episode_steps):
            action = policy.predict(obs, deterministic=True)[0]
            if kind == "white":
                action = action + size * rng.standard_normal(action.shape)
            elif kind == "gsde":
                with torch.no_grad():
                    latent = policy.mlp_extractor.forward_actor(torch.as_tensor(obs)).numpy()
                action = action + np.einsum("nj,njk->nk", latent, matrix)
                stds.append(np.exp(size) * np.linalg.norm(latent, axis=1))
            obs, _, _, _, info = task.step(np.clip(action, -1, 1).astype(np.float32))
            limit += info["reward_terms"]["limit"].mean()
            distance += info["reward_terms"]["distance"].mean()
        label = ("none (the deterministic lead)" if kind == "none" else
                 f"white, std {size:g} of the bound" if kind == "white" else
                 f"gSDE, log_std_init {size:g} (std {np.median(stds):.3f} of the bound)")
        print(f"exploration {label}: limit term {limit:.2f}, distance term {distance:.2f} per "
              f"episode ({len(paths)} paths)", flush=True)


def lead_excess(args: Args, seeds: list[int]) -> None:
    """On the paths limit_lead_only charges, a 2 s episode from 0.5 s: the acceleration excess
    (clipped per joint to [0, 1], summed) of the deterministic lead's joint goals, of the zero
    lead's goals solved beside them (TaskBatch's reference), and their difference (what
    limit_lead_only charges per unit of w_limit), by condition."""
    from panda_lead.limits import JOINT_ACC
    from panda_lead.task import LeadTask

    policy, base, paths, noise = _limit_world(args.models[0], 1.0, seeds)
    conditions = {"none": dict(obs_noise={}),
                  "latency 1 step": dict(obs_noise={}, obs_delay=1, action_delay=1),
                  "latency 3 steps": dict(obs_noise={}, obs_delay=3, action_delay=3),
                  "noise 1 mm": dict(obs_noise={k: 0.1 * v for k, v in noise.items()}),
                  "noise 1 cm": dict(obs_noise=noise)}
    for name, settings in conditions.items():
        task = LeadTask(base.replace(**settings), len(paths), nthread=2)
        task.rngs = [np.random.default_rng(s) for s in paths]  # the noise's draws, repeatable
        obs, goals, refs = task.reset(None, paths), [], []
        for _ in range(base.episode_steps):
            obs = task.step(policy.predict(obs, deterministic=True)[0])[0]
            goals.append(task.core.q_goal.copy())
            refs.append(task._ref_goal.copy())
        skip = int(round(0.5 / task.dt)) - 2
        lead, zero = (np.clip(np.abs(np.diff(np.array(q), 2, axis=0))[skip:] / task.dt ** 2
                              / JOINT_ACC - 1, 0, 1).sum(axis=(0, 2)).mean()
                      for q in (goals, refs))
        print(f"{name}: excess per episode, the lead's goals {lead:.1f}, the zero lead's "
              f"{zero:.1f}, difference {lead - zero:.1f} ({len(paths)} paths)", flush=True)


def lost_paths(args: Args, steps: int, seeds: list[int]) -> None:
    """The paths the condition's rival (deploy.RIVALS: the predicting analytic lead under
    latency, the filtered one under noise, else the analytic lead) is accepted on and the first
    model is not (counted the other way too): per lost path, the limit that binds, its peak /
    limit and when the peak comes (s), beside the rival's."""
    for cond in args.conditions:
        ctrls = controllers_for(cond, args.models[:1], steps)
        rival = next((r for r in RIVALS if r in ctrls), "Analytic")
        model = list(ctrls)[-1]  # (controllers_for puts the models last)
        rs = {name: _play(ctrls[name], seeds) for name in (rival, model)}
        checks = {name: accepted_by_arm(r) for name, r in rs.items()}
        lost = [s for s in seeds if checks[rival][s].accepted and not checks[model][s].accepted]
        gained = [s for s in seeds if checks[model][s].accepted and not checks[rival][s].accepted]
        print(f"{cond} {model} against {rival}, {len(seeds)} paths: lost {len(lost)}, gained "
              f"{len(gained)}", flush=True)
        for s in lost:
            r, c = rs[model][s], checks[model][s]
            print(f"  {s} {r.meta.get('shape', '?')}: {c.worst_limit} {c.worst_margin:.2f} at "
                  f"{c.worst_time:.2f} s"
                  f" (rival: {checks[rival][s].worst_limit} {checks[rival][s].worst_margin:.2f})",
                  flush=True)


def stack_weights(args: Args) -> None:
    """How much each stacked observation weighs in the policy's first layer: the norm of its
    columns, newest observation first, the mean over the models (which stack alike). Plays
    nothing; reads the weights."""
    from panda_lead.models import load_policy

    norms, stack = [], None
    for m in args.models:
        policy, env, _ = load_policy(m)
        if stack not in (None, env.get("obs_stack", 1)):
            raise UserError(f"{m} stacks {env.get('obs_stack', 1)} observations, the models "
                            f"before it {stack}: pass models that stack alike")
        stack = env.get("obs_stack", 1)
        w = policy.mlp_extractor.policy_net[0].weight.detach().numpy()
        norms.append(np.linalg.norm(w.reshape(w.shape[0], stack, -1), axis=(0, 2)))
    print(f"{len(norms)} models, {stack} stacked observations, first-layer column norm per "
          f"observation (newest first): {' / '.join(f'{n:.1f}' for n in np.mean(norms, 0))}")


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.core import control_dt
    from panda_lead.seeds import SELECT_SEEDS, TUNE_SEEDS

    for m in args.models:
        if not m.is_file():
            raise UserError(f"no model file {m}")
    for c in args.conditions:
        overrides(c)
    steps = int(round(5.0 / control_dt()))
    if not 0 <= args.on_selection <= len(SELECT_SEEDS):
        raise UserError(f"--on-selection must be 0..{len(SELECT_SEEDS)} (the selection set's "
                        f"size), got {args.on_selection}")
    seeds = list(SELECT_SEEDS[:args.on_selection] if args.on_selection else TUNE_SEEDS)
    if args.probe == "rival-lowpass":
        rival_lowpass(steps, seeds)
    elif args.probe == "margins":
        margins(args, steps, seeds)
    elif args.probe == "limit-excess":
        limit_excess(args, seeds[:30])
    elif args.probe == "limit-exploration":
        limit_exploration(args, seeds)
    elif args.probe == "lost-paths":
        lost_paths(args, steps, seeds)
    elif args.probe == "stack-weights":
        stack_weights(args)
    else:
        lead_excess(args, seeds)


if __name__ == "__main__":
    main(tyro.cli(Args, description=__doc__))
