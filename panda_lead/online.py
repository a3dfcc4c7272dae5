"""Online corrections a control engineer adds on top of any Cartesian lead (issue 37's "a lead
of another kind"): each wraps a controller's ``act(obs, task)`` and adds a correction (m) to
its lead, learned within the episode from the tip's tracking error e = target - tip.

- **integral**: c(t) = k_i * sum of e dt since ``start`` s. Causal: it cancels what stays
  constant over a trajectory (the bias the oracle's lead holds, docs/questions.md 9).
- **repetitive** (lap to lap): every path here is a closed loop with a known lap time T
  (trajectory params["lap_time"]), so the error one lap ago says what to add now:
  c(t) = Q[c(t - T) + k * e(t - T + advance)], with ``advance`` control steps of phase lead
  for the servos' lag, learning only from errors after ``start`` s (the swing from the home
  pose is no lap); Q averages over +-``smooth`` steps around those instants (a lap ago, so
  all of them are past), the low-pass that keeps a repetitive controller from amplifying
  what the servos cannot follow lap after lap. It knows the planned path's period, so it is
  a preview controller.

Either can fade in (``fade`` s): the errors just after ``start`` are learned from with a weight
rising smoothly from 0 to 1 (OnlineCorrection.weight) instead of all at once, whose kink the
real arm's joint-acceleration limit refuses (results/studies/online/tuning_fade.md).

Both are settings, never trained: studies/online_correction.py tunes them on the tuning seeds.
Under observation noise a played correction reads the measured error, the target reading minus
the tip reading, with the very draws the lead's observation carries (LeadTask.error_reading_noise);
its low-pass Q and the lap-to-lap gain are then its filter. Played on a lead
under latency (the lead's channel ``obs_delay`` steps late in and ``action_delay`` out, fixed
and known: studies/deploy.py's "latency k"), a correction runs where the lead runs: at step s
it knows the errors up to s - obs_delay, and what it returns acts at s + action_delay, so it
computes the correction for s + action_delay from the errors it has (a lap ago is long past:
the shortest lap is 29 steps). A late target camera (target_delay) is refused: the error it
reads is then not the tip's (it would need a prediction through the camera's delay; not
built). The in-loop correction (EnvConfig.repetitive_gain) runs in the world without latency
or noise only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

KINDS = ("integral", "repetitive")


@dataclass(frozen=True)
class OnlineCorrection:
    kind: str
    gain: float  # k_i (1/s) for integral, k (per lap) for repetitive
    advance: int = 0  # repetitive: control steps of phase lead
    smooth: int = 0  # repetitive: Q's half-width (control steps)
    start: float = 0.5  # s: errors before this are not learned from
    max_error: float = 0.0  # m: errors farther than this are not learned from (0: all are)
    fade: float = 0.0  # s: learning fades in over this time after ``start`` (0: switched on)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown online correction {self.kind!r}; choose from {KINDS}")
        if not (np.isfinite(self.gain) and self.gain >= 0 and self.advance >= 0
                and self.smooth >= 0 and self.start >= 0 and self.max_error >= 0
                and np.isfinite(self.fade) and self.fade >= 0):
            raise ValueError(f"online correction settings must be finite and >= 0: {self}")

    @property
    def knows_path(self) -> bool:
        return self.kind == "repetitive"

    def meta(self) -> dict:
        out = asdict(self)
        for name in ("max_error", "fade"):  # sets played before these existed record none
            if not out[name]:
                del out[name]
        return out

    def weight(self, t: np.ndarray) -> np.ndarray:
        """How much an error made at time ``t`` (s) is learned from: 0 before ``start``, then
        1 at once, or with ``fade`` rising as a smoothstep (3x^2 - 2x^3, flat at both ends) over
        ``fade`` seconds. Why: switched on at once, the first lap's correction starts with a kink
        in its slope (the low-pass's window fills step by step), and the 1 kHz command a real
        Panda receives turns that kink into a joint-acceleration spike past its limit
        (docs/questions.md 9, "A correction that fades in")."""
        return smooth_ramp(t, self.start, self.fade)


def smooth_ramp(t, start: float, length: float) -> np.ndarray:
    """0 before ``start``, then a smoothstep (3x^2 - 2x^3, flat at both ends) up to 1 over
    ``length`` s; a step at ``start`` when ``length`` is 0. The correction's fade and the
    planner's handover (preview.handover_weight) both ramp this way."""
    t = np.asarray(t, dtype=float)
    if not length:
        return (t >= start).astype(float)
    x = np.clip((t - start) / length, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class Corrector:
    """One correction's state over a batch of episode slots: ``corrector(task)`` is the
    correction (m, (N, 3)) for the task's present control step, learned from the tip's error
    e = target - tip at this step and the steps before. The state is per slot, cleared when a
    slot's episode starts (its time is 0). The one law both a played lead (``wrap``) and the
    env (EnvConfig.repetitive_gain, a policy trained with it in the loop) run."""

    def __init__(self, correction: OnlineCorrection):
        self.correction = correction
        self.state: dict = {}

    def __call__(self, task) -> np.ndarray:
        correction, state = self.correction, self.state
        pos = task.core.target()[0]
        error = pos - task.core.tip_pos + task.error_reading_noise()  # measured, noise and all
        n, dt = len(error), task.dt
        steps = np.rint(np.asarray(task.core.time) / dt).astype(int)  # this step's index
        # latency (module docstring): the errors known reach s - seen, the result acts at s + out
        seen, out = task.config.obs_delay, task.config.action_delay
        horizon = task.config.episode_steps + 1 + out
        if state.get("n") != n:
            state.update(n=n, c=np.zeros((n, horizon, 3)), e=np.zeros((n, horizon, 3)),
                         integral=np.zeros((n, 3)), lap=np.ones(n))
        fresh = steps == 0
        state["c"][fresh], state["e"][fresh], state["integral"][fresh] = 0.0, 0.0, 0.0
        if correction.kind == "repetitive" and fresh.any():  # a new path: its lap, in steps
            state["lap"][fresh] = [task.trajs[i].params["lap_time"] / dt
                                   for i in np.flatnonzero(fresh)]
        rows = np.arange(n)
        state["e"][rows, steps] = error  # the truth, read only once it is ``seen`` steps old
        known, acts = steps - seen, steps + out
        if correction.kind == "integral":
            w = (correction.weight(known * dt) * (known >= 0))[:, None]
            late = state["e"][rows, np.maximum(known, 0)]
            state["integral"] += np.where(w > 0, late * dt * w, 0.0)
            c = correction.gain * state["integral"]
        else:
            lap = state["lap"]
            c = np.zeros((n, 3))
            shifts = range(-correction.smooth, correction.smooth + 1)
            for j in shifts:  # Q: the mean over the window
                c_then, has_c = _at(state["c"], acts - lap + j, acts - 1)
                src = acts - lap + correction.advance + j
                e_then, has_e = _at(state["e"], src, known)
                learn = has_e * correction.weight(src * dt)
                if correction.max_error:  # an excursion is not a lap's error to repeat
                    learn *= np.linalg.norm(e_then, axis=1) <= correction.max_error
                c += np.where(has_c[:, None], c_then, 0.0) + np.where(
                    learn[:, None] > 0, correction.gain * learn[:, None] * e_then, 0.0)
            c /= len(shifts)
        state["c"][rows, acts] = c
        return c


def corrected_action(action: np.ndarray, c: np.ndarray, max_lead: float) -> np.ndarray:
    """The action (a lead in units of ``max_lead``) with the correction ``c`` (m) added,
    clipped to the lead's bound, as float32 as a policy's actions are (so that the law in the
    env and the law played on a lead are the same numbers, bit for bit)."""
    return np.clip(action + c / max_lead, -1.0, 1.0).astype(np.float32)


def check_world(cfg) -> None:
    """Refuse an env an online correction cannot run in: it reads the tip's measured error
    through a fixed, known latency at most, and no late target camera (module docstring)."""
    if cfg.action != "lead":
        raise ValueError("an online correction adds to a Cartesian lead: action 'lead'")
    if cfg.target_delay:
        raise ValueError("an online correction reads the tip's error: with a late target "
                         "camera it would read a stale one (not built)")
    if (cfg.obs_delay or cfg.action_delay) and cfg.random_delay:
        raise ValueError("an online correction runs through a fixed, known latency: not one "
                         "drawn per episode (random_delay)")


def wrap(act, correction: OnlineCorrection):
    """``act`` with ``correction`` added to its lead (clipped to the lead's bound)."""
    corrector = Corrector(correction)

    def corrected(obs, task) -> np.ndarray:
        action = np.asarray(act(obs, task), dtype=np.float64)
        check_world(task.config)
        if task.config.repetitive_gain:
            raise ValueError("this env already runs a repetitive correction in the loop "
                             "(EnvConfig.repetitive_gain): a second one would add to it")
        c = corrector(task)
        return corrected_action(action, c, task.config.max_lead)

    return corrected


def _at(buffer: np.ndarray, index: np.ndarray, now: np.ndarray):
    """Each slot's buffer at fractional step ``index`` (linear between steps), and whether both
    steps are recorded already (0 <= index, index's next step <= now)."""
    lo = np.floor(index).astype(int)
    ok = (lo >= 0) & (lo + 1 <= now)
    lo = np.clip(lo, 0, buffer.shape[1] - 2)
    frac = (index - np.floor(index))[:, None]
    rows = np.arange(len(index))
    value = buffer[rows, lo] * (1 - frac) + buffer[rows, lo + 1] * frac
    return value, ok
