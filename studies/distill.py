"""Distilling the ILC oracle into a causal policy (teacher-student, DAgger-style rounds).

    uv run studies/distill.py run --seed 1                  # one training seed -> results/runs/distill/
    uv run studies/distill.py run --seed 2 --rounds 3 --first 600 --per-round 400
    uv run studies/distill.py archive --name distill        # the chosen seed -> archive/distill.zip
    uv run studies/distill.py probe                         # does the observation determine the lead?
    uv run studies/distill.py diagnose --model archive/distill.zip  # where the student loses
    uv run studies/runs.py report --study distill           # then, from git alone:
    uv run studies/runs.py compare --study distill --against-study v5_err

The question: PPO's lead settles at ~1.3 cm where the ILC oracle (panda_lead/ilc.py, which sees
the future and the plant) settles at ~0.56 cm. Does supervised regression onto the oracle's
leads give a causal policy that closes much of that gap?

**Teacher.** On distillation trajectories (seeds.DISTILL_SEEDS: training seed k uses its own
slice, never a test, evaluation, tuning or pool seed), ``ilc.learn_leads`` (ILCConfig
defaults: 20 replays, gain 0.5, shift 8) finds each trajectory's best lead sequence, 5 s
episodes (500 steps, the test's length). Round 1 starts the oracle from the headline model's
lead (archive/v5_5m.zip, as `ikpd.py --controller ilc` does; that 15-D policy reads its own
columns of the student's observation, which holds its features at the same scales). Those
leads are then replayed (``ilc.replay_controller``) through the env with the student's
observation (default v5_err's 18-D: OBS_15 + tip_error) and every step gives one pair
(the observation the policy would see before step k, action = lead[k] / max_lead).

**Student.** An SB3 PPO built as training builds one (MlpPolicy, 64x64 tanh; log_std set to
``--log-std``, low: the student acts by its mean); its actor mean (mlp_extractor.policy_net +
action_net) is fitted by MSE to the pairs (Adam, minibatches, ``--epochs`` over all pairs
each round, from scratch each round, seeded, one torch thread). 10% of each round's
trajectories are held out for the validation loss.

**DAgger rounds** (``--rounds``, round 1 included): the current student plays fresh
distillation trajectories, the oracle is started from the student's own leads (so its final
trajectory stays near the states the student visits), the new pairs join the old ones, and
the student is fitted again. After each round the student is evaluated on the fixed
evaluation set (seeds.EVAL_SET, training's `evaluate`); the round with the lowest evaluation
error is the run's best model (as training's best_model.zip), the last round its final model.

**Output.** A run folder runs/distill/<name>/ shaped like a training run's (best_model.zip and
final_model.zip with their sidecars, best.json, config.json, tb/progress.csv with one
evaluation line per round, rounds.json with the per-round losses and oracle errors), then
``studies/runs.py summarize`` writes results/runs/<study>/seed_<k>.json in its own format:
its "timesteps" are the teacher's env steps (every oracle replay, the replays that record the
pairs, the student's own plays inside the oracle's first replay), not RL steps. ``archive``
picks the seed by runs.py's rule (lowest best evaluation error) and archives it.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from panda_lead.config import OBS_15, EnvConfig
from panda_lead.errors import UserError, check_plain_name, exit_on_user_error, parse_cli
from panda_lead.ilc import ILCConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
import runs as run_summaries  # noqa: E402  (studies/runs.py: the summary format, the rule)

STUDENT_FEATURES = OBS_15 + ("tip_error",)
# Settings that shape the plant (not what the policy observes): the teacher's init model and
# the student must run on the same plant for the oracle's leads to mean the same.
OBS_ONLY = ("obs_features", "obs_stack", "obs_noise", "obs_delay")


@dataclass
class Args:
    command: tyro.conf.Positional[Literal["run", "archive", "probe", "diagnose"]]
    """run: one training seed, its run folder and summary; archive: the chosen seed's model;
    probe: students of other observations and sizes on the same teacher data; diagnose: where
    a student (--model) loses against its teacher."""
    seed: int = 1
    """Training seed k (1..10): its distillation seeds, its network's initialisation."""
    rounds: int = 3
    """Data rounds, the first (oracle from the headline model) included; later ones DAgger."""
    first: int = 600
    """Teacher trajectories in round 1."""
    per_round: int = 400
    """Teacher trajectories in each later (DAgger) round."""
    steps: int = 500
    """Episode length (control steps; 500 = 5 s, the test's)."""
    ilc: ILCConfig = field(default_factory=ILCConfig)
    """The oracle (defaults: the tuned ones)."""
    init_model: Path | None = None
    """Round 1's oracle starts from this model's lead (default archive/v5_5m, the headline when
    the distill runs were made)."""
    obs_features: tuple[str, ...] = STUDENT_FEATURES
    """The student's observation."""
    epochs: int = 30
    """Passes over all pairs per fit."""
    batch_size: int = 512
    """Minibatch size of the regression."""
    learning_rate: float = 1e-3
    """Adam's step size."""
    log_std: float = -3.0
    """The student's log std (it acts by its mean; low, so a stochastic play stays close)."""
    val_frac: float = 0.1
    """Share of each round's trajectories held out for the validation loss."""
    study: str = "distill"
    """Summaries go to results/runs/<study>/, run folders to <runs-dir>/."""
    runs_dir: Path = Path("runs/distill")
    """Where run folders are written."""
    summarize: bool = True
    """Write the study summary (the 1,000 test seeds played once, ~1 min)."""
    name: str = "distill"
    """archive: the archive name."""
    force: bool = False
    """Replace an existing summary or archived name."""
    nthread: int = 0
    """MuJoCo batch threads (0: its default)."""
    probe_n: int = 200
    """probe, diagnose: teacher trajectories."""
    model: Path | None = None
    """diagnose: the student."""


# --- pieces (imported by tests/test_distill.py) ----------------------------------------------
def student_config(features=STUDENT_FEATURES, steps: int = 500) -> EnvConfig:
    return EnvConfig(obs_features=tuple(features), episode_steps=steps)


def distill_seeds(k: int) -> range:
    from panda_lead.seeds import DISTILL_SEEDS, DISTILL_SLICE

    if not 1 <= k <= len(DISTILL_SEEDS) // DISTILL_SLICE:
        raise UserError(f"--seed must be 1..{len(DISTILL_SEEDS) // DISTILL_SLICE}, got {k}")
    start = DISTILL_SEEDS.start + (k - 1) * DISTILL_SLICE
    return range(start, start + DISTILL_SLICE)


def column_picker(inner: EnvConfig, outer: EnvConfig):
    """Columns of ``outer``'s observation that make ``inner``'s (the same features, each at its
    fixed scale), so a model trained on ``inner`` can run on ``outer``'s env."""
    from panda_lead.config import obs_layout

    if inner.obs_stack != 1 or outer.obs_stack != 1:
        raise UserError("column_picker: stacked observations are not supported")
    spans = {f: (a, b) for f, a, b in obs_layout(outer.obs_features)}
    missing = [f for f in inner.obs_features if f not in spans]
    if missing:
        raise UserError(f"the init model observes {', '.join(missing)}, which the student's "
                        "observation lacks")
    return np.concatenate([np.arange(*spans[f]) for f, _, _ in obs_layout(inner.obs_features)])


def same_plant(a: EnvConfig, b: EnvConfig) -> None:
    da, db = a.to_dict(), b.to_dict()
    differ = [k for k in da if k not in OBS_ONLY and da[k] != db[k]]
    if differ:
        raise UserError(f"the init model's env differs from the student's in {', '.join(differ)}"
                        "; the oracle's leads would be another plant's")


def init_from_model(model: Path | None, config: EnvConfig):
    """The act function of ``model``'s policy (default the headline) on ``config``'s env."""
    from panda_lead import controllers
    from panda_lead.harness import evaluation_config
    from panda_lead.models import DEFAULT_MODEL, archived, load_policy

    policy, env_dict, _ = load_policy(model or archived(DEFAULT_MODEL))
    inner, _ = evaluation_config(env_dict, None, config.episode_steps)
    same_plant(inner, config)
    cols = column_picker(inner, config)
    act = controllers.make_policy(policy)
    return lambda obs, task: act(np.asarray(obs)[:, cols], task)


def record_pairs(config: EnvConfig, leads: np.ndarray, seeds, nthread: int = 0):
    """Replay ``leads`` (N, T, 3) on ``seeds`` through ``config``'s env -> (obs (N, T, d),
    actions (N, T, 3), errors (N,) mean |tip - target| in m of the replay): the observation
    the policy sees before step k and the action that plays lead[k]."""
    from panda_lead.ilc import replay_controller
    from panda_lead.rollout import iter_record

    seeds = [int(s) for s in seeds]
    row = {s: i for i, s in enumerate(seeds)}
    n, steps = len(seeds), config.episode_steps
    dim = None
    obs_out = actions = None
    filled = np.zeros((n, steps), dtype=bool)
    replay = replay_controller(leads, seeds, config.max_lead)

    def act(obs, task):
        nonlocal obs_out, actions, dim
        a = replay(obs, task)
        if obs_out is None:
            dim = obs.shape[1]
            obs_out = np.zeros((n, steps, dim), np.float32)
            actions = np.zeros((n, steps, 3), np.float32)
        rows = np.array([row[int(s)] for s in task.traj_seeds])
        k = np.broadcast_to(task.core.step_count, (len(rows),))
        live = k < steps
        obs_out[rows[live], k[live]] = obs[live]
        actions[rows[live], k[live]] = a[live]
        filled[rows[live], k[live]] = True
        return a

    errors = np.full(n, np.nan)
    for r in iter_record(config, act, seeds, nthread=nthread):
        errors[row[r.seed]] = r.error.mean() if r.meta.get("failure") is None else np.nan
    ok = filled.all(axis=1) & np.isfinite(errors)  # a failed episode gives no pairs
    return obs_out[ok], actions[ok], errors, ok


def build_student(config: EnvConfig, seed: int, log_std: float):
    """A PPO as training builds one for this env (MlpPolicy, 64x64 tanh), on a stand-in env
    with the spaces (it is fitted, never stepped)."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.utils import set_random_seed

    from panda_lead.models import spaces_for

    obs_space, act_space = spaces_for(config)

    class Spaces(gym.Env):
        observation_space, action_space = obs_space, act_space

    set_random_seed(seed)
    return PPO("MlpPolicy", Spaces(), seed=seed, device="cpu", verbose=0,
               policy_kwargs=dict(net_arch=[64, 64], activation_fn=torch.nn.Tanh,
                                  log_std_init=log_std))


def actor_mean(policy, x):
    feats = policy.extract_features(x, policy.features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(feats))


def fit(policy, obs: np.ndarray, act: np.ndarray, val_obs: np.ndarray, val_act: np.ndarray,
        epochs: int, batch_size: int, lr: float, seed: int, log=print) -> list[dict]:
    """MSE regression of the actor's mean onto the actions; -> per-epoch train/val losses."""
    import torch

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
    opt = torch.optim.Adam(params, lr=lr)
    x, y = torch.as_tensor(obs), torch.as_tensor(act)
    vx, vy = torch.as_tensor(val_obs), torch.as_tensor(val_act)
    gen = np.random.default_rng(seed)
    history = []
    policy.set_training_mode(True)
    for epoch in range(epochs):
        perm = torch.as_tensor(gen.permutation(len(x)))
        total = 0.0
        for i in range(0, len(x), batch_size):
            idx = perm[i:i + batch_size]
            loss = torch.nn.functional.mse_loss(actor_mean(policy, x[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        with torch.no_grad():
            val = float(torch.nn.functional.mse_loss(actor_mean(policy, vx), vy)) if len(vx) \
                else float("nan")
        history.append({"epoch": epoch + 1, "train_mse": total / len(x), "val_mse": val})
        if epoch == 0 or (epoch + 1) % 10 == 0 or epoch + 1 == epochs:
            log(f"  epoch {epoch + 1:3d}: train mse {total / len(x):.5f}, val mse {val:.5f}")
    policy.set_training_mode(False)
    return history


def split(seeds, frac: float) -> np.ndarray:
    """Held-out mask over ``seeds``: the last ``frac`` of them (at least one when frac > 0)."""
    n = len(seeds)
    hold = int(round(frac * n)) if frac > 0 else 0
    hold = max(hold, 1) if frac > 0 and n > 1 else hold
    mask = np.zeros(n, dtype=bool)
    mask[n - hold:] = True
    return mask


# --- one run ---------------------------------------------------------------------------------
def run(args: Args, log=print) -> Path:
    """One training seed: rounds of teacher data and fits; writes the run folder and returns it."""
    import torch

    from panda_lead import controllers
    from panda_lead.ilc import learn_leads
    from panda_lead.models import save_model, write_json_atomic
    from panda_lead.training.evaluation import evaluate

    clock = time.perf_counter()
    config = student_config(args.obs_features, args.steps)
    slice_ = distill_seeds(args.seed)
    counts = [args.first] + [args.per_round] * (args.rounds - 1)
    if args.rounds < 1 or min(counts) < 1 or sum(counts) > len(slice_):
        raise UserError(f"--rounds/--first/--per-round: need 1..{len(slice_)} trajectories in "
                        "all, at least one per round")
    run_dir = Path(args.runs_dir) / f"{args.study}__{args.seed}"
    if run_dir.exists() and not args.force:
        raise UserError(f"{run_dir} exists; add --force to redo it")
    (run_dir / "tb").mkdir(parents=True, exist_ok=True)
    settings = {k: v for k, v in asdict(args).items() if k not in ("command", "name", "force",
                                                                    "summarize", "runs_dir")}
    settings = json.loads(json.dumps(settings, default=str))
    settings.update(preset=args.study, timesteps_meaning=(
        "teacher env steps: every ILC replay (its first replay is the init policy's or the "
        "student's own play) and the replays that record the pairs"),
        net_arch=[64, 64], student_env=config.to_dict(),
        init_model=str(args.init_model or "archive/v5_5m.zip"))
    write_json_atomic(run_dir / "config.json", settings)
    torch.set_num_threads(1)
    model = build_student(config, args.seed, args.log_std)
    pool = {"obs": [], "act": [], "val_obs": [], "val_act": []}
    teacher_steps, rounds, start = 0, [], 0
    best = None
    for r, count in enumerate(counts, 1):
        seeds = list(slice_[start:start + count])
        start += count
        if r == 1:
            init, who = init_from_model(args.init_model, config), "the headline model"
        else:
            init, who = controllers.make_policy(model.policy), "the student"
        t0 = time.perf_counter()
        log(f"round {r}: oracle on {count} trajectories ({seeds[0]}-{seeds[-1]}), started from "
            f"{who}, {args.ilc.iterations} replays")
        leads, hist = learn_leads(config, seeds, None, args.ilc, init, nthread=args.nthread,
                                  on_iteration=lambda j, m: log(f"  replay {j}: {m:.3f} cm")
                                  if j in (0, 1, 5, 10) or j == args.ilc.iterations else None)
        obs, act, errs, ok = record_pairs(config, leads, seeds, args.nthread)
        teacher_steps += (args.ilc.iterations + 2) * count * args.steps
        held = split(seeds, args.val_frac)[ok]
        pool["obs"].append(obs[~held].reshape(-1, obs.shape[-1]))
        pool["act"].append(act[~held].reshape(-1, 3))
        pool["val_obs"].append(obs[held].reshape(-1, obs.shape[-1]))
        pool["val_act"].append(act[held].reshape(-1, 3))
        replay_cm = 100 * float(np.nanmean(errs))
        log(f"  oracle: first replay {hist[0]:.3f} cm -> {hist[-1]:.3f} cm (replayed for the "
            f"pairs: {replay_cm:.3f} cm), {int(ok.sum())} trajectories, "
            f"{time.perf_counter() - t0:.0f} s")
        model = build_student(config, args.seed, args.log_std)  # each fit from scratch
        x = np.concatenate(pool["obs"])
        log(f"  fitting on {len(x):,} pairs")
        losses = fit(model.policy, x, np.concatenate(pool["act"]),
                     np.concatenate(pool["val_obs"]), np.concatenate(pool["val_act"]),
                     args.epochs, args.batch_size, args.learning_rate, args.seed * 1000 + r, log)
        metrics = evaluate(controllers.make_policy(model.policy), config, args.steps)
        log(f"  student on the evaluation set: {metrics['mean_error_cm']:.3f} cm "
            f"({time.perf_counter() - clock:.0f} s so far)")
        rounds.append({"round": r, "trajectories": count, "first_seed": seeds[0],
                       "oracle_history_cm": hist, "oracle_replayed_cm": replay_cm,
                       "pairs_total": int(len(x)), "teacher_steps": teacher_steps,
                       "fit": losses, "eval": metrics})
        model.num_timesteps = teacher_steps
        side = {"env_config": config.to_dict(), "train_config": settings,
                "timesteps": int(teacher_steps),
                "wall_time_s": round(time.perf_counter() - clock, 1)}
        save_model(model, run_dir / f"round_{r}.zip", {**side, "eval_metrics": metrics})
        if best is None or metrics["mean_error_cm"] < best[1]["mean_error_cm"]:
            best = (r, metrics)
            save_model(model, run_dir / "best_model.zip", {**side, "eval_metrics": metrics})
            write_json_atomic(run_dir / "best.json", {"timesteps": teacher_steps, **metrics,
                                                      "round": r})
    save_model(model, run_dir / "final_model.zip", side)
    with open(run_dir / "tb" / "progress.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["eval/timesteps", "eval/mean_error_cm", "round"])
        for x in rounds:
            w.writerow([x["teacher_steps"], x["eval"]["mean_error_cm"], x["round"]])
    write_json_atomic(run_dir / "rounds.json", {"rounds": rounds, "best_round": best[0]})
    log(f"done: {run_dir} (best round {best[0]}: {best[1]['mean_error_cm']:.3f} cm on the "
        f"evaluation set), {time.perf_counter() - clock:.0f} s")
    return run_dir


def summarize(args: Args, run_dir: Path) -> Path:
    """results/runs/<study>/seed_<k>.json by runs.py's own summarize, plus the per-round table."""
    run_summaries.summarize(run_summaries.Args(command="summarize", runs=[run_dir],
                                               study=args.study, force=args.force))
    path = run_summaries.RUNS_DIR / args.study / f"seed_{args.seed}.json"
    summary = json.loads(path.read_text())
    rounds = json.loads((run_dir / "rounds.json").read_text())["rounds"]
    summary["rounds"] = [{k: x[k] for k in ("round", "trajectories", "first_seed",
                                            "oracle_replayed_cm", "pairs_total",
                                            "teacher_steps")}
                         | {"oracle_first_replay_cm": x["oracle_history_cm"][0],
                            "final_train_mse": x["fit"][-1]["train_mse"],
                            "final_val_mse": x["fit"][-1]["val_mse"],
                            "eval_mean_error_cm": x["eval"]["mean_error_cm"]}
                         for x in rounds]
    path.write_text(json.dumps(summary, indent=1) + "\n")
    return path


def archive(args: Args) -> None:
    from panda_lead.training.archive import archive_model

    chosen = run_summaries.choose_run(run_summaries.load_study(args.study))
    run_dir = Path(args.runs_dir) / chosen["run"]
    if not run_dir.is_dir():
        raise UserError(f"{run_dir} is not here: archive on the machine that ran it")
    path = archive_model(run_dir, check_plain_name(args.name, "--name"), force=args.force,
                         caveats=(f"Distilled from the ILC oracle (studies/distill.py), not "
                                  f"trained by RL: its 'timesteps' are the teacher's env "
                                  f"steps. Seed {chosen['seed']} of study {args.study}, chosen "
                                  "by the lowest evaluation-set error.",))
    print(f"{args.study}: seed {chosen['seed']} (evaluation error "
          f"{chosen['best']['mean_error_cm']:.3f} cm) archived as {path}")


PROBE_FEATURES = {
    "v5 (15-D)": OBS_15,
    "v5_err (18-D)": STUDENT_FEATURES,
    "v5_err + tip_error_avg (21-D)": STUDENT_FEATURES + ("tip_error_avg",),
    "v5_err + joint_pos, joint_vel (32-D)": STUDENT_FEATURES + ("joint_pos", "joint_vel"),
}


def probe(args: Args, log=print) -> None:
    import torch

    from panda_lead.core import control_dt
    from panda_lead.ilc import learn_leads
    from panda_lead.seeds import DISTILL_SEEDS, DISTILL_SLICE

    wide = student_config(STUDENT_FEATURES + ("tip_error_avg", "joint_pos", "joint_vel"),
                          args.steps)
    seeds = list(range(DISTILL_SEEDS.stop - DISTILL_SLICE, DISTILL_SEEDS.stop))[:args.probe_n]
    t0 = time.perf_counter()
    leads, hist = learn_leads(wide, seeds, None, args.ilc, init_from_model(args.init_model, wide),
                              nthread=args.nthread)
    obs, act, errs, ok = record_pairs(wide, leads, seeds, args.nthread)
    held = split(seeds, args.val_frac)[ok]
    log(f"probe: oracle on {len(seeds)} trajectories ({seeds[0]}-{seeds[-1]}): "
        f"{hist[0]:.3f} -> {hist[-1]:.3f} cm, {time.perf_counter() - t0:.0f} s; actions' "
        f"variance per axis {act[held].reshape(-1, 3).var(axis=0).round(4).tolist()}\n")
    log("| student observation | net | train MSE | held-out MSE | held-out R^2 | RMS lead error "
        "(cm) | constant per trajectory, t >= 0.5 s (cm) |")
    log("|---|---|---|---|---|---|---|")
    total_var = act[held].reshape(-1, 3).var(axis=0).sum()
    for label, feats in PROBE_FEATURES.items():
        cols = column_picker(student_config(feats), wide)
        for arch in ([64, 64], [256, 256]) if feats == STUDENT_FEATURES else ([64, 64],):
            config = student_config(feats, args.steps)
            model = build_student(config, args.seed, args.log_std)
            if arch != [64, 64]:
                from stable_baselines3 import PPO

                model = PPO("MlpPolicy", model.env, seed=args.seed, device="cpu",
                            policy_kwargs=dict(net_arch=arch, activation_fn=torch.nn.Tanh,
                                               log_std_init=args.log_std))
            o = obs[..., cols]
            hist_fit = fit(model.policy, o[~held].reshape(-1, len(cols)),
                           act[~held].reshape(-1, 3), o[held].reshape(-1, len(cols)),
                           act[held].reshape(-1, 3), args.epochs, args.batch_size,
                           args.learning_rate, args.seed, log=lambda s: None)
            with torch.no_grad():
                x = torch.as_tensor(o[held].reshape(-1, len(cols)))
                pred = actor_mean(model.policy, x).numpy().reshape(act[held].shape)
            res = (pred - act[held]) * wide.max_lead * 100  # cm, (n, T, 3)
            settled = res[:, int(round(0.5 / control_dt())):]  # t >= 0.5 s, as bias.py
            const = np.linalg.norm(settled.mean(axis=1), axis=-1)  # per trajectory
            mse = hist_fit[-1]["val_mse"]
            log(f"| {label} | {'x'.join(map(str, arch))} | {hist_fit[-1]['train_mse']:.5f} | "
                f"{mse:.5f} | {1 - 3 * mse / total_var:.3f} | "
                f"{np.sqrt(np.mean(np.sum(res ** 2, axis=-1))):.2f} | {const.mean():.2f} |")


def diagnose(args: Args, log=print) -> None:
    import torch

    from panda_lead import controllers
    from panda_lead.core import control_dt
    from panda_lead.ilc import learn_leads, replay_controller, smooth
    from panda_lead.models import load_policy
    from panda_lead.rollout import record_many
    from panda_lead.seeds import DISTILL_SEEDS, DISTILL_SLICE

    if args.model is None:
        raise UserError("diagnose needs --model (a student's zip)")
    policy, env_dict, _ = load_policy(args.model)
    config = student_config(env_dict["obs_features"], args.steps)
    seeds = list(range(DISTILL_SEEDS.stop - DISTILL_SLICE, DISTILL_SEEDS.stop))[:args.probe_n]
    leads, hist = learn_leads(config, seeds, None, args.ilc,
                              init_from_model(args.init_model, config), nthread=args.nthread)
    obs, act, errs, ok = record_pairs(config, leads, seeds, args.nthread)
    seeds_ok = [s for s, good in zip(seeds, ok, strict=True) if good]
    with torch.no_grad():
        pred = actor_mean(policy, torch.as_tensor(obs.reshape(-1, obs.shape[-1]))).numpy()
    pred = np.clip(pred.reshape(act.shape), -1, 1)
    k0 = int(round(0.5 / control_dt()))

    def settled(act_fn):
        rs = record_many(config, act_fn, seeds_ok)
        return np.array([100 * r.error[k0:].mean() for r in rs]), rs

    m = config.max_lead
    rows = {"oracle's leads replayed": settled(replay_controller(leads[ok], seeds_ok, m))[0],
            "student, closed loop": settled(controllers.make_policy(policy))[0],
            "student's leads on the oracle's states, open loop":
                settled(replay_controller(pred * m, seeds_ok, m))[0],
            "oracle's leads smoothed over 11 steps":
                settled(replay_controller(smooth(leads[ok], 11), seeds_ok, m))[0]}
    log(f"diagnose {args.model} on {len(seeds_ok)} fresh trajectories ({seeds[0]}-{seeds[-1]}); "
        f"oracle {hist[0]:.3f} -> {hist[-1]:.3f} cm (episode mean)\n")
    log("| played | settled error, mean [median] (cm) |\n|---|---|")
    for label, v in rows.items():
        log(f"| {label} | {v.mean():.2f} [{np.median(v):.2f}] |")
    res = (pred - act)[:, k0:] * m * 100  # cm, the student's lead error on the oracle's states
    const = res.mean(axis=1, keepdims=True)
    slow = smooth(res, 11) - const
    fast = res - smooth(res, 11)
    rms = lambda x: float(np.sqrt(np.mean(np.sum(x ** 2, axis=-1))))  # noqa: E731
    log(f"\nthe student's lead error on the oracle's states, t >= 0.5 s (RMS of the 3-D error, "
        f"cm): all {rms(res):.2f} = constant per trajectory {rms(np.broadcast_to(const, res.shape)):.2f}"
        f" + slow (11-step average less the constant) {rms(slow):.2f} + fast {rms(fast):.2f}; "
        f"the oracle's leads themselves: RMS {rms(act[:, k0:] * m * 100):.2f}, their fast part "
        f"{rms((act - smooth(act, 11))[:, k0:] * m * 100):.2f}")


@exit_on_user_error
def main(args: Args) -> None:
    check_plain_name(args.study, "--study")
    if args.command == "archive":
        archive(args)
        return
    if args.command in ("probe", "diagnose"):
        {"probe": probe, "diagnose": diagnose}[args.command](args, log=lambda s: print(s,
                                                                                      flush=True))
        return
    path = run_summaries.RUNS_DIR / args.study / f"seed_{args.seed}.json"
    if args.summarize and path.exists() and not args.force:
        raise UserError(f"{path} exists; add --force to redo it")
    run_dir = run(args, log=lambda s: print(s, flush=True))
    if args.summarize:
        print(f"wrote {summarize(args, run_dir)}")


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
