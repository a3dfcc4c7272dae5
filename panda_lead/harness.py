"""The evaluation harness: how every controller is built and played on seeds, and how a rollout
set is written. eval.py, ikpd.py and the studies all go through it, so they evaluate alike.

Three rules live here and nowhere else:
- **The evaluation env.** A model runs on the env its sidecar describes, except its
  training-only randomisations (observation noise, latency and its random draw, termination on
  self-collision, the training trajectories' speed cap and shapes): an evaluation starts from
  none of them, and a study or a flag sets each explicitly. So a "delay of 3 steps" is exactly
  3 steps for every controller, and an episode in which the arm touches itself is played to
  the end and scored (a failure is data, not a reason to drop a trajectory).
- **A controller's identity** (rollout.identity: controller, model hash, controller settings,
  env): a rollout set holds one identity; the writer and metrics.py apply the same rule.
- **Writing a set**: under the folder's lock, streamed batch by batch (memory stays that of one
  batch), each file atomic; an interrupted set keeps the files it finished.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from . import controllers
from .atomicio import folder_lock
from .config import EnvConfig
from .errors import UserError, did_you_mean
from .ilc import ILCConfig, learn_leads, oracle_meta, replay_controller
from .rollout import identity, iter_record, read_meta, rollout_path, save

CONTROLLERS = ("policy", "classical", "analytic", "ilc", *controllers.PREVIEW_RIVALS)
# Settings that only shape training; an evaluation starts from none of them.
TRAINING_ONLY = {"obs_noise": {}, "obs_delay": 0, "action_delay": 0, "random_delay": False,
                 "random_noise": False, "nominal_share": 0.0, "split_conditions": False,
                 "target_delay": 0, "noisy_ik_target": False,
                 "terminate_on_collision": False, "max_peak_speed": None, "shapes": None}


def evaluation_config(env_config: EnvConfig | dict, overrides: dict | None = None,
                      steps: int | None = None) -> tuple[EnvConfig, list[str]]:
    """The env an evaluation runs: ``env_config`` without its training-only randomisations,
    then ``overrides`` (flags or a study's level, merged key by key) and the episode length.
    Returns it and the names of the model's settings that were dropped (to say so)."""
    base = EnvConfig.from_dict(env_config) if isinstance(env_config, dict) else env_config
    dropped = [k for k, v in TRAINING_ONLY.items() if getattr(base, k) != v
               and k not in (overrides or {}) and k not in ("shapes", "max_peak_speed")]
    config = base.replace(**TRAINING_ONLY).merged(overrides or {})
    if steps is not None:
        config = config.replace(episode_steps=steps)
    return config, dropped


@dataclass
class Controller:
    """A controller ready to play: its act function (or, for the ILC oracle, how to make one
    for given seeds), the env it plays on, and the meta its rollouts record."""

    name: str
    config: EnvConfig
    meta: dict
    act: object = None  # act(obs, task) -> actions; None for the oracle until it has learnt
    ilc: ILCConfig | None = None
    init_act: object = None  # the oracle's first replay
    init_config: EnvConfig | None = None  # the env of that first replay (default: config)
    policy: object = None  # the loaded policy, for callers that need it
    dropped: list[str] = field(default_factory=list)

    def act_for(self, seeds, shapes=None, on_iteration=None):
        """The act function for these seeds: the controller's own, or the oracle's replay of
        the lead sequences it learns on exactly these trajectories."""
        if self.ilc is None:
            return self.act
        leads, _ = learn_leads(self.init_config or self.config, seeds, shapes, self.ilc,
                               self.init_act, on_iteration=on_iteration)
        return replay_controller(leads, seeds, self.config.max_lead)


def model_labels(paths) -> list[str]:
    """A short, distinct label per model path for a study's tables: its file name without
    .zip, or, where names repeat (each run's best_model.zip), its run folder's name and the
    file's. Two paths that still share a label are one model named twice: a user error, not
    a row that silently replaces another."""
    paths = [Path(p) for p in paths]
    stems = [p.stem for p in paths]
    labels = [f"{p.parent.name}/{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in paths]
    for label in labels:
        if labels.count(label) > 1:
            raise UserError(f"two models would share the label {label!r}: "
                            "give each model once (or rename one)")
    return labels


def build(name: str, steps: int, model: Path | None = None, overrides: dict | None = None,
          tau: float | None = None, stochastic: bool = False, ilc: ILCConfig | None = None
          ) -> Controller:
    """A named controller on its evaluation env. The policy (and the oracle started from it)
    runs on its model's env; the others on the default env, or the model's when one is given
    (so two controllers compared on a video see the same task)."""
    from .models import DEFAULT_MODEL, archived, load_policy

    if name not in CONTROLLERS:
        raise UserError(f"unknown controller {name!r}" + did_you_mean(name, CONTROLLERS))
    meta: dict = {"controller": name, "model": None}
    policy, env_config = None, EnvConfig()
    needs_model = name == "policy" or (name == "ilc" and (ilc or ILCConfig()).init == "policy")
    if needs_model or model is not None:
        path = model or archived(DEFAULT_MODEL)
        policy, env_dict, side = load_policy(path)
        env_config = EnvConfig.from_dict(env_dict)
        if needs_model:
            meta.update(model=str(path), model_sha256=side["model_sha256"])
    _check_overrides(env_config, overrides or {}, name)
    config, dropped = evaluation_config(env_config, overrides, steps)
    if config.feedforward and not needs_model:  # a baseline on a residual model's env plays
        config = config.replace(feedforward=False)  # without it: else it is that rival
    if env_config.repetitive_gain and not needs_model:  # ... and without the model's in-loop
        config = config.without_correction()  # correction (online_correction.py adds it)
    if name == "policy":
        act = controllers.make_policy(policy, deterministic=not stochastic)
        return Controller(name, config, meta, act, policy=policy, dropped=dropped)
    if config.action != "lead":  # the baselines and the oracle are Cartesian leads
        config = config.replace(action="lead")
    if name == "classical":
        return Controller(name, config, meta, controllers.classical, dropped=dropped)
    if name == "analytic":
        tau = controllers.DEFAULT_TAU if tau is None else tau
        meta["tau"] = tau
        return Controller(name, config, meta, controllers.make_analytic(tau), dropped=dropped)
    if name == "future_target":  # the preview rivals know the planned path (issue 37)
        meta["tau"] = controllers.FUTURE_TAU if tau is None else tau
        return Controller(name, config, {**meta, "knows_path": True},
                          controllers.make_future_target(meta["tau"]), dropped=dropped)
    if name == "feedforward":
        meta["tau"] = controllers.FEEDFORWARD_TAU if tau is None else tau
        meta.update(knows_path=True, gain=controllers.FEEDFORWARD_GAIN,
                    tau_ik=controllers.FEEDFORWARD_TAU_IK, clip=controllers.FEEDFORWARD_CLIP)
        return Controller(name, config.replace(action="joint_target"), meta,
                          controllers.make_feedforward(meta["tau"]), dropped=dropped)
    if name == "feedforward_plan":  # the plan open-loop where the arm can follow it
        if tau is not None:
            raise UserError("--tau does not apply to feedforward_plan (it follows the plan "
                            "half a control period ahead; its fallback is the feedforward's)")
        meta.update(knows_path=True, handover=list(controllers.PLAN_HANDOVER),
                    fallback=dict(controllers.FEEDFORWARD_SETTINGS))
        return Controller(name, config.replace(action="joint_target"), meta,
                          controllers.make_planned_feedforward(), dropped=dropped)
    ilc = ilc or ILCConfig()
    starts = {"analytic": controllers.make_analytic(controllers.DEFAULT_TAU),
              "zero": controllers.classical}
    init = (controllers.make_policy(policy) if ilc.init == "policy" else starts[ilc.init])
    meta["ilc"] = oracle_meta(ilc, meta.get("model_sha256") if ilc.init == "policy" else None)
    # A model trained with the lap-to-lap correction in the loop starts the oracle as it runs,
    # correction and all; the corrected leads it records are then replayed without it
    return Controller(name, config.without_correction(), meta, ilc=ilc, init_act=init,
                      init_config=config, policy=policy, dropped=dropped)


def _check_overrides(model_env: EnvConfig, overrides: dict, name: str) -> None:
    """Refuse flags that contradict the model up front (instead of failing mid-episode): the
    action kind and the observation layout are the model's own."""
    if name != "policy":
        return
    for key in ("action", "obs_features", "obs_stack"):
        if key in overrides:
            want = getattr(model_env.merged({key: overrides[key]}), key)
            if want != getattr(model_env, key):
                raise UserError(f"--env.{key.replace('_', '-')} {overrides[key]!r} contradicts the "
                                f"model, which was trained with {key} "
                                f"{getattr(model_env, key)!r}; the policy cannot run otherwise")


def _claim(folder: Path, mine: tuple, force: bool) -> None:
    """Check that a rollout folder holds only rollouts of this identity; with ``force``, delete
    the others (so a set never mixes two). Call under the folder's lock."""
    others = []
    for f in sorted(folder.glob("seed_*.npz")):
        try:
            theirs = identity(read_meta(f))
        except UserError:
            theirs = ("unreadable file",)
        if theirs != mine:
            others.append((f, theirs))
    if others and not force:
        f, theirs = others[0]
        raise UserError(f"{folder} holds {len(others)} rollouts of another controller, model, "
                        f"setting or env ({f.name}: {theirs[0]}); choose another --prefix, or add "
                        "--force to delete them and write this set")
    for f, _ in others:
        f.unlink()


def write_set(ctrl: Controller, seeds: list[int], shape: str | None, root: Path, prefix: str,
              force: bool = False, echo=print) -> int:
    """Play ``seeds`` and write one rollout file each under root/prefix, as they finish;
    returns how many were written. Ctrl-C keeps the files already written and says so."""
    folder = Path(root) / prefix
    shapes = [shape] * len(seeds)
    written = 0
    with folder_lock(folder, "the rollout set"):
        mine = identity({**ctrl.meta, "env": ctrl.config.to_dict()})
        _claim(folder, mine, force)
        try:
            act = ctrl.act_for(seeds, shapes, on_iteration=lambda j, m: echo(
                f"ILC replay {j}: mean error over the set {m:.2f} cm"))
            for r in iter_record(ctrl.config, act, seeds, shapes, ctrl.meta):
                save(r, rollout_path(prefix, r.seed, root))
                written += 1
                note = f"  FAILED: {r.meta['failure']}" if r.meta.get("failure") else ""
                echo(f"seed {r.seed:4d} {r.shape:6s} mean error {100 * r.error.mean():6.2f} cm"
                     f"{note}")
        except KeyboardInterrupt:
            raise UserError(f"interrupted: {written} of {len(seeds)} rollouts written to "
                            f"{folder}/ (each complete); rerun the command to write them all"
                            ) from None
    return written
