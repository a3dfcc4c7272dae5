"""The ceiling: an iterative-learning-control (ILC) ORACLE for the lead.

Not a controller anyone could deploy. For each trajectory it replays the whole episode again
and again, from the same start, and corrects its lead sequence with the errors the previous
replay made: it sees the future (the whole target path) and the plant (its exact response),
which no policy does. What it reaches is a bound on what a bounded Cartesian lead on this
IK+PD core can do, so every learned result can be read against it.

The update, per trajectory, iteration j -> j+1 (``leads`` is (T, 3), one lead per control step,
the error e[k] = target - tip after step k):

    leads[k] += gain * smooth(e)[k + shift]        clipped to +-max_lead per axis

A lead applied in step k moves the tip only in later steps, and the IK+PD lags by a few steps,
so a lead is corrected by the error ``shift`` steps after it; ``smooth`` is a centred moving
average over ``taps`` steps (it keeps the correction from amplifying step-to-step noise).
A replay that does not lower a trajectory's mean error is discarded for that trajectory (the
best sequence so far is kept) and that trajectory's gain is halved for its next try. The
gain, shift, first replay and number of iterations are chosen on the tuning seeds
(`uv run studies/ilc_tune.py`), never the test seeds. Every replay of every trajectory runs as
one batch, like every other controller.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .config import EnvConfig
from .errors import UserError, check_typed_fields
from .rollout import iter_record

INITS = ("analytic", "zero", "policy")


@dataclass(frozen=True)
class ILCConfig:
    """The oracle's settings (defaults chosen on the tuning seeds: results/studies/ilc/ilc_tuning.md)."""

    gain: float = field(default=0.5, metadata={"range": (0.0, 2.0)})
    """Share of the (shifted, smoothed) error added to the lead per iteration."""
    shift: int = field(default=8, metadata={"range": (0, 50)})
    """The lead of step k is corrected by the error this many steps later."""
    taps: int = field(default=5, metadata={"range": (1, 51)})
    """Width (steps) of the centred moving average applied to the error."""
    iterations: int = field(default=20, metadata={"range": (0, 500)})
    """Replays after the first (each one episode per trajectory)."""
    init: str = "policy"
    """The first replay's lead: policy (a model's, --model, default the headline model),
    analytic (the analytic lead) or zero (classical)."""

    def __post_init__(self):
        check_typed_fields(self, "ilc.")
        if self.init not in INITS:
            raise UserError(f"ilc.init must be one of {', '.join(INITS)}, got {self.init!r}")


def smooth(x: np.ndarray, taps: int) -> np.ndarray:
    """Centred moving average over ``taps`` steps along axis 1 of (N, T, 3); near the ends the
    window shrinks to the steps that exist."""
    if taps <= 1:
        return x
    steps = x.shape[1]
    c = np.concatenate([np.zeros_like(x[:, :1]), np.cumsum(x, axis=1)], axis=1)
    k = np.arange(steps)
    lo = np.maximum(k - taps // 2, 0)
    hi = np.minimum(k - taps // 2 + taps, steps)
    return (c[:, hi] - c[:, lo]) / (hi - lo)[None, :, None]


def replay_controller(leads: np.ndarray, seeds, max_lead: float):
    """An act function that plays a fixed lead sequence per trajectory seed: slot i (whatever
    batch it is in) looks its row up by its trajectory seed and reads the row at its step."""
    order = np.argsort(np.asarray(seeds))
    sorted_seeds = np.asarray(seeds)[order]
    scale = 1.0 / max_lead if max_lead > 0 else 0.0

    def act(obs, task) -> np.ndarray:
        rows = order[np.searchsorted(sorted_seeds, task.traj_seeds)]
        k = np.minimum(task.core.step_count, leads.shape[1] - 1)
        return (leads[rows, k] * scale).astype(np.float32)

    return act


def _play(config: EnvConfig, act, seeds, shapes, nthread: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One replay of every seed, streamed (no rollout is kept: memory is that of one batch
    plus these arrays, ~100 kB less per seed than a list of rollouts) -> (leads (N, T, 3),
    errors target - tip (N, T, 3), mean error per seed in m). An episode that ends early (an
    unstable simulation, a self-collision the env terminates on) is charged as metrics charges
    any failure (metrics.pairing.charged: the arm frozen where it failed, no lead after), so a
    failed replay counts at full length and is never kept as an improvement by accident."""
    from .metrics.pairing import charged

    row = {s: i for i, s in enumerate(seeds)}
    steps = config.episode_steps
    leads, errors = np.zeros((len(seeds), steps, 3)), np.zeros((len(seeds), steps, 3))
    mean = np.empty(len(seeds))
    for r in iter_record(config, act, seeds, shapes, nthread=nthread):
        r, _ = charged(r)
        i = row[r.seed]
        leads[i], errors[i] = r.lead, r.target_pos - r.ee_pos
        mean[i] = r.error.mean()
    return leads, errors, mean


def learn_leads(config: EnvConfig, seeds, shapes, ilc: ILCConfig, init_act, nthread: int = 0,
                on_iteration=None) -> tuple[np.ndarray, list[float]]:
    """Run the oracle on every seed at once -> (best lead sequences (N, T, 3) in metres, the
    mean error (cm) over all seeds after each replay, the first replay included).
    ``init_act`` is the first replay's controller; ``on_iteration(j, mean_cm)`` reports.
    Under ``config.repetitive_gain`` (a start with the lap-to-lap correction in the loop) the
    first replay runs with it and records the corrected leads; the replays run without it."""
    if config.action != "lead":
        raise UserError("the ILC oracle corrects a Cartesian lead: it needs action 'lead'")
    seeds = [int(s) for s in seeds]
    if len(set(seeds)) != len(seeds):
        raise UserError("the ILC oracle needs each trajectory seed once")
    bound = config.max_lead
    leads, errors, best_err = _play(config, init_act, seeds, shapes, nthread)
    history = [float(100 * best_err.mean())]
    if on_iteration:
        on_iteration(0, history[-1])
    steps = leads.shape[1]
    replay_config = config.without_correction()
    ahead = np.minimum(np.arange(steps) + ilc.shift, steps - 1)
    gain = np.full((len(seeds), 1, 1), ilc.gain)
    for j in range(1, ilc.iterations + 1):
        trial = np.clip(leads + gain * smooth(errors, ilc.taps)[:, ahead], -bound, bound)
        _, played_errors, err = _play(replay_config, replay_controller(trial, seeds, bound),
                                      seeds, shapes, nthread)
        better = err < best_err  # keep only improvements, trajectory by trajectory
        leads[better] = trial[better]
        best_err[better] = err[better]
        gain[~better] *= 0.5
        errors[better] = played_errors[better]
        del played_errors
        history.append(float(100 * best_err.mean()))
        if on_iteration:
            on_iteration(j, history[-1])
    return leads, history


def oracle_meta(ilc: ILCConfig, start_sha256: str | None = None,
                start_online: dict | None = None, start_follow_plan: bool = False,
                start_clearance: float = 0.0) -> dict:
    """What a rollout of the oracle records about it (rollout meta "ilc"): its settings and the
    lead it started from, ``start_model_sha256`` (the starting model's SHA-256; None when it
    started from the analytic or zero lead), ``start_online`` (the online correction the
    start had on top, panda_lead/online.py; None: none) and ``start_follow_plan`` (the start
    ran with the planner's hand, EnvConfig.follow_plan, and so does every replay: the oracle
    then learns the lead of the episodes and stretches the plan does not hold) and
    ``start_clearance`` (the start and every replay on the collision-aware IK with this
    clearance, m; 0: the plain IK). The oracle belongs to that start: metrics.py refuses to
    pair it with another model or the same model corrected, handed over or on another IK, and
    a results script compares the hash with the model's sidecar to rebuild a stale oracle."""
    meta = {"oracle": True, **asdict(ilc), "start_model_sha256": start_sha256}
    if start_online is not None:  # (older oracles' files have no such key: none)
        meta["start_online"] = start_online
    if start_follow_plan:  # (older oracles' files have no such key: no hand)
        meta["start_follow_plan"] = True
    if start_clearance:  # (... nor this one: the plain IK)
        meta["start_clearance"] = float(start_clearance)
    return meta


def oracle_start(meta: dict) -> tuple[str, str | None]:
    """(the first replay's lead, its model's SHA-256 or None) from an oracle rollout's meta.
    Older oracle files carried the starting model's hash only as the rollout's model_sha256."""
    ilc = meta.get("ilc") or {}
    init = ilc.get("init", "policy")
    sha = ilc.get("start_model_sha256", meta.get("model_sha256") if init == "policy" else None)
    return init, sha


def check_oracle_start(oracle_meta_: dict, compared: dict[str, dict], oracle_name: str) -> None:
    """Refuse an oracle started from a model that is none of the compared sets' models: its
    ceiling belongs to that model, not to these (``compared``: set name -> a rollout's meta).
    An oracle started from the analytic or zero lead is no model's (nor is a set that is no
    ILC oracle's); an oracle that started from a model it did not record is refused too."""
    init, sha = oracle_start(oracle_meta_)
    if not (oracle_meta_.get("ilc") or {}).get("oracle") or init != "policy":
        return
    models = {name: m.get("model_sha256") for name, m in compared.items()
              if m.get("model_sha256")}
    if sha is None:
        raise UserError(f"{oracle_name} started from a model it does not record; rebuild the "
                        "oracle from the compared model")
    if models and sha not in models.values():
        name, theirs = next(iter(models.items()))
        raise UserError(f"{oracle_name} started from the model {sha[:12]}, not from {name}'s "
                        f"({theirs[:12]}): rebuild the oracle from that model")
    online = (oracle_meta_.get("ilc") or {}).get("start_online")
    mine = {name: compared[name].get("online") for name, m in models.items() if m == sha}
    if mine and online not in mine.values():
        name, theirs = next(iter(mine.items()))
        raise UserError(f"{oracle_name} started from that model with {_said(online)}, {name} "
                        f"runs it with {_said(theirs)}: rebuild the oracle from that controller "
                        "(studies/online_correction.py play --oracle)")
    mine = _env_facts((oracle_meta_.get("ilc") or {}).get("start_follow_plan"),
                      (oracle_meta_.get("ilc") or {}).get("start_clearance"))
    theirs = {name: _env_facts(env.get("follow_plan"), (env.get("ik") or {}).get("clearance"))
              for name, env in ((n, compared[n].get("env") or {}) for n, m in models.items()
                                if m == sha)}
    if theirs and mine not in theirs.values():
        name, other = next(iter(theirs.items()))
        flags = (" --follow-plan" if other[0] else "") + (
            f" --clearance {other[1]:g}" if other[1] else "")
        raise UserError(f"{oracle_name} started from that model {_said_env(mine)}, {name} runs "
                        f"it {_said_env(other)}: rebuild the oracle from that controller "
                        f"(studies/online_correction.py play --oracle{flags})")


def _env_facts(follow_plan, clearance) -> tuple[bool, float]:
    """(the planner's hand on, the IK's clearance in m): what a start and its replays share."""
    return bool(follow_plan), float(clearance or 0.0)


def _said_env(facts: tuple[bool, float]) -> str:
    hand, clearance = facts
    ik = f"on the collision-aware IK ({clearance:g} m)" if clearance else "on the plain IK"
    return f"{'with' if hand else 'without'} the planner's hand, {ik}"


def _said(correction: dict | None) -> str:
    return f"the {correction['kind']} correction" if correction else "no online correction"
