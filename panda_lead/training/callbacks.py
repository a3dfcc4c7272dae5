"""SB3 callbacks of a training run, and what they lean on: the signal flag, the run's clock, the
progress.csv logger. Each callback is a plain module-level class that takes its settings in
``__init__`` (as rl_zoo3's callbacks.py does)."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.logger import CSVOutputFormat

from .. import trajectory
from ..controllers import classical, make_analytic, make_policy
from .evaluation import evaluate


def say(text: str) -> None:
    """Print a line without tearing the progress bar."""
    from tqdm.auto import tqdm

    tqdm.write(text)
    sys.stdout.flush()


class RunClock:
    """Wall time of a run across resumes: the seconds before this process (from the checkpoint's
    sidecar) plus the seconds since it started."""

    def __init__(self, before_s: float = 0.0):
        self.before_s = float(before_s)
        self.start = time.time()

    def elapsed(self) -> float:
        return self.before_s + time.time() - self.start


class SignalFlag:
    """SIGINT and SIGTERM set a flag that makes learn() stop at the next step (the model is then
    saved); a second signal raises KeyboardInterrupt at once. Only in the main thread."""

    def __init__(self):
        self.received: int | None = None
        self._old: dict = {}

    def _handle(self, signum, frame):
        if self.received is not None:
            raise KeyboardInterrupt
        self.received = signum
        print(f"\n{signal.Signals(signum).name}: stopping at the next step and saving "
              "(again to stop at once)", file=sys.stderr, flush=True)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}


class TrackingEval(BaseCallback):
    """Evaluates on the fixed evaluation set every ``config.eval_freq`` steps, logs cm figures
    beside the two baselines, prints one line per evaluation and keeps the best model
    (``save_best(model, timesteps, metrics)``). ``on_eval(timesteps, metrics)`` may return
    False to stop the run (sweep.py's pruner). Ties keep the earlier model: only a strictly
    lower error replaces the best."""

    def __init__(self, config, run_dir: Path, clock: RunClock, save_best, on_eval=None,
                 best: tuple[float, int | None] = (float("inf"), None)):
        super().__init__()
        self.config, self.run_dir, self.clock = config, run_dir, clock
        self.save_best, self.on_eval = save_best, on_eval
        # (error, step) of the best so far: a resumed run's comes from resume_best
        self.best, self.best_step = best
        self.last_eval = 0
        self.baselines: dict[str, dict] = {}

    def _on_training_start(self) -> None:
        self.last_eval = self.num_timesteps
        config = self.config
        if not config.eval_freq:
            return
        # The baselines are Cartesian leads (zero, analytic): a run with another action is
        # compared with them on the same task with the lead action. On a residual's env
        # (feedforward) they play without the feedforward, as eval.py's do (a zero lead
        # there IS the feedforward rival, and the analytic lead on top of it leads twice);
        # the rival the residual starts from is a third line.
        as_lead = config.env.without_correction().replace(action="lead", feedforward=False)
        self.baselines = {"classical": evaluate(classical, as_lead, config.eval_steps),
                          "analytic": evaluate(make_analytic(), as_lead, config.eval_steps)}
        if config.env.feedforward:
            self.baselines["feedforward"] = evaluate(
                classical, config.env.replace(action="lead"), config.eval_steps)

    def _on_step(self) -> bool:
        config = self.config
        if config.eval_freq and self.num_timesteps - self.last_eval >= config.eval_freq:
            res = self.run_eval()
            if self.on_eval is not None and self.on_eval(self.num_timesteps, res) is False:
                return False  # e.g. an Optuna pruner said stop
            stop = config.stop_below_cm
            if stop is not None and res["mean_error_cm"] < stop:
                say(f"evaluation error {res['mean_error_cm']:.2f} cm < {stop} cm: stopping "
                    f"at {self.num_timesteps} steps, {self.clock.elapsed():.0f} s")
                return False
        return True

    def run_eval(self) -> dict:
        self.last_eval = self.num_timesteps
        res = evaluate(make_policy(self.model), self.config.env, self.config.eval_steps)
        for k, v in res.items():
            self.logger.record(f"eval/{k}", v)
        # The baselines at every evaluation step, so they draw as lines across the run.
        for name, base in self.baselines.items():
            for k, v in base.items():
                self.logger.record(f"eval_{name}/{k}", v)
        self.logger.record("eval/wall_time_s", self.clock.elapsed())
        self.logger.record("eval/timesteps", self.num_timesteps)
        classical_cm = self.baselines["classical"]["mean_error_cm"]
        self.logger.record("eval/improvement_over_classical_cm", classical_cm - res["mean_error_cm"])
        new_best = res["mean_error_cm"] < self.best
        if new_best:
            self.best, self.best_step = res["mean_error_cm"], self.num_timesteps
            self.save_best(self.model, self.num_timesteps, res)
        self.logger.dump(self.num_timesteps)
        a, c = self.baselines["analytic"], self.baselines["classical"]
        say(f"step {self.num_timesteps:>10,}  error {res['mean_error_cm']:5.2f} cm  "
            f"in 5 cm band {res['in_band_pct']:5.1f}%   (classical {classical_cm:.2f} cm / "
            f"{c['in_band_pct']:.1f}%, analytic {a['mean_error_cm']:.2f} cm / "
            f"{a['in_band_pct']:.1f}%" + _rival_note(self.baselines) + ")"
            + ("  best" if new_best else ""))
        return res


def _rival_note(baselines: dict) -> str:
    """The feedforward rival a residual run starts from, where there is one."""
    f = baselines.get("feedforward")
    return "" if f is None else f", feedforward {f['mean_error_cm']:.2f} cm / {f['in_band_pct']:.1f}%"


class AtomicCheckpoint(CheckpointCallback):
    """SB3's checkpoint schedule (``save_freq`` counted in calls, i.e. total steps / n_envs),
    each checkpoint written by ``save(model, path, timesteps)``: atomically and with its
    sidecar, so a process killed mid-write never leaves a half zip that --resume would trust."""

    def __init__(self, save_freq: int, save_path: str, save):
        super().__init__(save_freq=save_freq, save_path=save_path, name_prefix="model")
        self.save = save

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            self.save(self.model, Path(self._checkpoint_path(extension="zip")), self.num_timesteps)
        return True


class Progress(BaseCallback):
    """A progress bar whose total is the number of steps the run will really do, and the signal
    check: after SIGINT/SIGTERM, learn() stops at the next step."""

    def __init__(self, total: int, show: bool, signals: SignalFlag | None = None):
        super().__init__()
        self.total, self.show, self.signals = total, show, signals
        self.bar = None

    def _on_training_start(self) -> None:
        if self.show:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=self.total, unit="step", unit_scale=True, dynamic_ncols=True)

    def _on_step(self) -> bool:
        if self.bar is not None:
            self.bar.update(min(self.training_env.num_envs, self.total - self.bar.n))
        return self.signals is None or self.signals.received is None

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


class TrainingDiverged(Exception):
    """The policy's weights stopped being finite after an update (at ``steps``)."""

    def __init__(self, steps: int):
        super().__init__(f"the policy's weights are not finite after {steps} steps")
        self.steps = steps


class FiniteWeights(BaseCallback):
    """Before each rollout, checks that the last update left the policy's weights finite; if
    not (a diverged update, e.g. from absurd reward weights or learning rate), raises
    `TrainingDiverged` out of learn(), so the loop reports it in one line and the last good
    checkpoint stays the newest, instead of failing deep inside torch."""

    def _on_rollout_start(self) -> None:
        import torch

        if not all(torch.isfinite(p).all() for p in self.model.policy.parameters()):
            raise TrainingDiverged(self.num_timesteps)

    def _on_step(self) -> bool:
        return True


def speed_cap(step: int, start: float, steps: int) -> float | None:
    """The curriculum's peak-speed cap at a training step: linear from start to the fastest
    trajectory (trajectory.MAX_SPEED), then none."""
    if step >= steps:
        return None
    return start + (trajectory.MAX_SPEED - start) * step / steps


class SpeedCurriculum(BaseCallback):
    """Sets the envs' speed cap before each rollout, through SB3's env_method (the batched env,
    SubprocVecEnv and DummyVecEnv all take it)."""

    def __init__(self, vec, start: float, steps: int):
        super().__init__()
        self.vec, self.start, self.steps = vec, start, steps

    def _on_rollout_start(self) -> None:
        cap = speed_cap(self.num_timesteps, self.start, self.steps)
        self.vec.env_method("set_speed_cap", cap)
        self.logger.record("train/speed_cap", cap or 0.0)

    def _on_step(self) -> bool:
        return True


def best_record(side: dict) -> dict:
    """best.json's content for a best model's (verified) sidecar: its step, its evaluation and
    its SHA-256, so that best.json is bound to the model it describes."""
    return {"timesteps": side["timesteps"], **side["eval_metrics"],
            "model_sha256": side["model_sha256"]}


def resume_best(run_dir: Path) -> tuple[float, int | None]:
    """(error, step) of a resumed run's best so far, from best_model.zip's own sidecar (its
    eval_metrics, bound to the zip by its SHA-256), never from best.json alone: best.json is a
    file anyone can edit or lose. A best.json that is missing, damaged or says anything else is
    rewritten from the sidecar (with a note); a best model whose sidecar cannot be checked is
    one error line, so that a better best is never overwritten by guesswork."""
    from ..errors import UserError
    from ..models import ModelError, verify, write_json_atomic

    best_zip, best_file = run_dir / "best_model.zip", run_dir / "best.json"
    if not best_zip.exists():
        if best_file.exists():
            say(f"note: {best_file} describes no best_model.zip; the next evaluation is the "
                "best so far")
        return float("inf"), None
    try:
        side = verify(best_zip)
    except ModelError as exc:
        raise UserError(f"--resume {run_dir}: its best model cannot be checked ({exc}); restore "
                        "its sidecar, or move best_model.zip away to resume without it") from None
    metrics = side.get("eval_metrics")
    error = metrics.get("mean_error_cm") if isinstance(metrics, dict) else None
    if isinstance(error, bool) or not isinstance(error, int | float) or not math.isfinite(error):
        raise UserError(f"--resume {run_dir}: best_model.zip's sidecar records no evaluation "
                        "error (eval_metrics); move it away to resume without it")
    want = best_record(side)
    try:
        have = json.loads(best_file.read_text()) if best_file.is_file() else None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        have = "damaged"
    if have != want:
        why = ("missing" if have is None else "unreadable" if have == "damaged"
               else "not what the best model's sidecar says")
        write_json_atomic(best_file, want)
        say(f"note: {best_file} was {why}; rewritten from best_model.zip's sidecar "
            f"({error:.2f} cm at {side['timesteps']:,} steps)")
    return float(error), side["timesteps"]


def read_progress(path: Path) -> str:
    """A run's progress.csv as text ("" when absent); UserError when it cannot be continued."""
    from ..errors import UserError

    if path.is_dir() or (path.exists() and not path.is_file()):
        raise UserError(f"{path} is not a file (the run's log goes there); move it away to "
                        "resume")
    if not path.exists():
        return ""
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start}), so the "
                        "run's log cannot be continued; move it away to resume") from None


class _AppendingCSV(CSVOutputFormat):
    """SB3's CSV writer, with its two in-place writes made atomic.

    SB3 opens its file with "w+", which truncates an existing progress.csv, and when a row
    brings new keys (the first evaluation's, after the first training rows) it rewrites the
    whole file in place from its start: a crash, or a reader, in the middle sees old and new
    rows mixed. Here both are a new file written beside progress.csv and renamed over it
    (atomicio): a resumed run's old rows are copied in, and a new key's column is added in a
    new copy; a crash at any moment leaves the run's whole log under its name."""

    def __init__(self, filename: Path):  # (SB3's own would truncate: it is not called)
        path = Path(filename)
        old = read_progress(path)
        self.keys, self.separator, self.quotechar = [], ",", '"'
        self._path = path
        if old.strip():
            self._replace(old if old.endswith("\n") else old + "\n")
            self.keys = old.splitlines()[0].split(",")
        else:
            self._replace("")

    def _replace(self, text: str) -> None:
        """Make ``text`` the file's whole content, atomically, and append from there on."""
        from ..atomicio import atomic_write

        with atomic_write(self._path, ".tmp.csv") as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
        old_file = getattr(self, "file", None)
        self.file = open(self._path, "a+", encoding="utf-8")  # noqa: SIM115 (kept open, as SB3's)
        if old_file is not None:
            old_file.close()

    def write(self, key_values, key_excluded, step: int = 0) -> None:
        from stable_baselines3.common.logger import filter_excluded_keys

        shown = filter_excluded_keys(key_values, key_excluded, "csv")
        extra = [k for k in shown if k not in self.keys]
        if extra:  # the new columns, in a new copy of the file (SB3's order and padding)
            self.file.flush()
            lines = self._path.read_text(encoding="utf-8").splitlines()
            pad, keys = self.separator * len(extra), self.keys + extra
            self._replace(",".join(keys) + "\n" + "".join(f"{row}{pad}\n" for row in lines[1:]))
            self.keys = keys
        super().write(key_values, key_excluded, step)  # no new key now: one appended row


def make_logger(folder: Path):
    from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat

    folder.mkdir(parents=True, exist_ok=True)
    tb = TensorBoardOutputFormat(str(folder))
    # One chart with the policy and its baselines (TensorBoard's "Custom Scalars" tab; the
    # feedforward line exists only in a residual's run).
    lines = [f"eval{who}/{{}}" for who in ("", "_classical", "_analytic", "_feedforward")]
    tb.writer.add_custom_scalars({"tracking": {
        "mean error (cm)": ["Multiline", [k.format("mean_error_cm") for k in lines]],
        "time in 5 cm band (%)": ["Multiline", [k.format("in_band_pct") for k in lines]]}})
    return Logger(str(folder), [tb, _AppendingCSV(folder / "progress.csv")])

