"""Rollout files: one episode of one controller on one seed, as a compressed .npz.

Layout on disk: ``rollouts/<prefix>/seed_<NNNN>.npz``. Arrays, one row per control step (T rows):

| key             | shape  | unit   | meaning                                                  |
|-----------------|--------|--------|----------------------------------------------------------|
| t               | (T,)   | s      | time at the end of the control step                      |
| ee_pos          | (T, 3) | m      | tip-site position, world frame                           |
| target_pos      | (T, 3) | m      | target position at time t                                |
| target_vel      | (T, 3) | m/s    | target velocity (analytic)                               |
| target_acc      | (T, 3) | m/s^2  | target acceleration (analytic)                           |
| lead            | (T, 3) | m      | Cartesian lead added to the IK target during this step   |
| qpos            | (T, 7) | rad    | arm joint positions                                      |
| qvel            | (T, 7) | rad/s  | arm joint velocities                                     |
| self_collision  | (T,)   | bool   | two non-adjacent arm links touch                         |
| collision_depth | (T,)   | m      | deepest self-collision penetration (0 when none)         |
| reachable       | (T,)   | bool   | the target lies inside the arm's reachable workspace     |
| q_goal          | (T, 7) | rad    | joint goals commanded to the PD (IK output) this step;   |
|                 |        |        | optional: files written before it lack it (None)         |
| meta            | ()     | str    | JSON: seed, shape, controller, model, duration, dt, env  |

What a read checks (`load`, `load_prefix`), so that no number is computed on a file the repo
did not write as it stands: every size before decompressing; the shapes above with one T;
float arrays as floats and flags as bool; meta's seed, shape, dt and duration; at most
duration / dt rows, ``t`` the end of each dt step; the target the meta's seed and shape give
(trajectory.sample(seed, shape).at(t)); one file per seed, named by its meta's seed.

Files are written atomically (temporary name, then ``os.replace``): an interrupted write never
leaves a half file that a later command would trust.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import trajectory
from .atomicio import atomic_write
from .config import MAX_EPISODE_STEPS, failure_of
from .errors import UserError
from .seeds import MAX_SEED
from .trajectory import SHAPES

ROLLOUT_DIR = Path("rollouts")
ARRAY_KEYS = (
    "t", "ee_pos", "target_pos", "target_vel", "target_acc", "lead",
    "qpos", "qvel", "self_collision", "collision_depth", "reachable",
)
# Columns added later: written always, read when present (older files lack them: None).
OPTIONAL_KEYS = ("q_goal",)


@dataclass
class Rollout:
    t: np.ndarray
    ee_pos: np.ndarray
    target_pos: np.ndarray
    target_vel: np.ndarray
    target_acc: np.ndarray
    lead: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    self_collision: np.ndarray
    collision_depth: np.ndarray
    reachable: np.ndarray
    meta: dict = field(default_factory=dict)
    q_goal: np.ndarray | None = None  # the commanded joint goals (limits.check reads them)

    @property
    def seed(self) -> int:
        return int(self.meta["seed"])

    @property
    def shape(self) -> str:
        return str(self.meta.get("shape", "?"))

    @property
    def dt(self) -> float:
        return float(self.meta.get("dt", self.t[1] - self.t[0] if len(self.t) > 1 else 0.01))

    @property
    def duration(self) -> float:
        return float(self.meta.get("duration", len(self.t) * self.dt))

    @property
    def error(self) -> np.ndarray:
        """Tracking error per step, metres: |ee - target|."""
        return np.linalg.norm(self.ee_pos - self.target_pos, axis=1)


def rollout_path(prefix: str, seed: int, root: Path = ROLLOUT_DIR) -> Path:
    return Path(root) / prefix / f"seed_{seed:04d}.npz"


class RolloutError(UserError):
    """A rollout file that cannot be read (truncated, not a rollout). Not a ValueError: a
    caller that turns ValueErrors into user errors would hide real bugs with it."""


class NoRollouts(UserError, FileNotFoundError):
    """A prefix with no rollout files."""


def save(rollout: Rollout, path: Path) -> Path:
    """Write atomically: a temporary file in the same folder, then rename over the target. A
    full disk is one UserError line (atomicio), the previous file intact."""
    path = Path(path)
    arrays = {k: np.asarray(getattr(rollout, k)) for k in ARRAY_KEYS}
    arrays.update({k: np.asarray(getattr(rollout, k)) for k in OPTIONAL_KEYS
                   if getattr(rollout, k) is not None})
    arrays["meta"] = np.array(json.dumps(rollout.meta, sort_keys=True))
    with atomic_write(path, ".tmp.npz") as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


# What a damaged .npz raises inside numpy and zipfile (truncated, garbage, wrong member).
_READ_ERRORS = (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error,
                UnicodeDecodeError)

# A rollout file may come from elsewhere, so reading one is bounded: every size below is checked
# before anything is decompressed. Far above any real rollout (the longest episode,
# MAX_EPISODE_STEPS steps of (T, 7) float64, is a 5.6 MB array), far below what would hurt.
MAX_ARRAY_BYTES = 2 * MAX_EPISODE_STEPS * 7 * 8 + 4096
MAX_META_BYTES = 2**20
MAX_FILE_BYTES = 64 * 2**20
# Each array's columns per row ((T,) when absent), and whether it is a flag (bool) array.
COLUMNS = {"ee_pos": 3, "target_pos": 3, "target_vel": 3, "target_acc": 3, "lead": 3,
           "qpos": 7, "qvel": 7, "q_goal": 7}
FLAG_KEYS = ("self_collision", "reachable")
# Physical bounds: a finite value beyond them is a damaged file, never a motion of this arm (it
# would overflow the metrics and drop the seed from one set). NaN and inf are not refused here:
# metrics names such seeds and leaves them out of every set.
LIMITS = {"t": (1e6, "s, longer than any episode"),
          "ee_pos": (100.0, "m, farther than any position"),
          "target_pos": (100.0, "m, farther than any position"),
          "lead": (100.0, "m, farther than any position"),
          "collision_depth": (100.0, "m, deeper than any contact"),
          "target_vel": (1e4, "m/s, faster than any speed"),
          "qvel": (1e4, "rad/s, faster than any speed"),
          "target_acc": (1e6, "m/s^2, beyond any acceleration"),
          "qpos": (1e4, "rad, beyond any joint angle"),
          "q_goal": (1e4, "rad, beyond any joint angle")}


def _damaged(path: Path, what: str) -> RolloutError:
    return RolloutError(f"{path}: not a valid rollout file ({what}); the file is damaged, "
                        "write it again")


def _read_array(z: zipfile.ZipFile, path: Path, key: str, limit: int) -> np.ndarray:
    """One .npy member, decompressed only up to ``limit`` bytes and parsed without trusting its
    header: the shape and dtype it declares must account for exactly the bytes it holds."""
    try:
        info = z.getinfo(f"{key}.npy")
    except KeyError:
        raise _damaged(path, f"no {key} array") from None
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise _damaged(path, f"{key} is compressed with method {info.compress_type}, which "
                       "numpy never writes")
    if info.file_size > limit:
        raise _damaged(path, f"{key} would expand to {info.file_size:,} bytes, more than the "
                       f"{limit:,} a rollout array may")
    with z.open(info) as f:
        raw = f.read(limit + 1)
    if len(raw) > limit:
        raise _damaged(path, f"{key} expands beyond {limit:,} bytes")
    buf = io.BytesIO(raw)
    version = np.lib.format.read_magic(buf)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(buf)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(buf)
    else:
        raise _damaged(path, f"{key} is an .npy of version {version}")
    if dtype.hasobject or dtype.kind not in "biufU":
        raise _damaged(path, f"{key} has dtype {dtype}")
    count = math.prod(shape)
    if count * dtype.itemsize != len(raw) - buf.tell():
        raise _damaged(path, f"{key}'s header says {shape} {dtype}, but it holds "
                       f"{len(raw) - buf.tell():,} bytes")
    arr = np.frombuffer(raw, dtype=dtype, count=count, offset=buf.tell())
    return arr.reshape(shape, order="F" if fortran else "C").copy()


def _open_checked(path: Path) -> zipfile.ZipFile:
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise _damaged(path, f"{size:,} bytes, more than the {MAX_FILE_BYTES:,} any rollout "
                       "file is")
    return zipfile.ZipFile(path)


def _read_meta(z: zipfile.ZipFile, path: Path) -> dict:
    arr = _read_array(z, path, "meta", MAX_META_BYTES)
    if arr.shape != () or arr.dtype.kind != "U":
        raise _damaged(path, f"meta must be one string, got {arr.shape} {arr.dtype}")
    try:
        meta = json.loads(str(arr))
    except json.JSONDecodeError as exc:
        raise _damaged(path, f"meta is not JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise _damaged(path, f"meta must be a JSON object, got {type(meta).__name__}")
    return meta


def check_meta(meta: dict, path: Path) -> None:
    """The metadata every reader relies on: an integer seed, a shape name, a positive finite
    dt and duration. RolloutError naming the file and the field."""
    seed = meta.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise _damaged(path, f"meta seed must be an integer in 0..{MAX_SEED}, got {seed!r}")
    if not isinstance(meta.get("shape"), str):
        raise _damaged(path, f"meta shape must be a name, got {meta.get('shape')!r}")
    if meta["shape"] not in SHAPES:
        raise _damaged(path, f"meta shape must be one of {', '.join(SHAPES)}, got "
                       f"{meta['shape'][:40]!r}")
    for key in ("dt", "duration"):
        v = meta.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not (
                math.isfinite(v) and v > 0):
            raise _damaged(path, f"meta {key} must be a positive finite number, got {v!r}")


def check_arrays(fields: dict[str, np.ndarray], path: Path) -> None:
    """Shapes (T,), (T, 3), (T, 7) with one T >= 1; float dtypes, flags bool (an integer
    ``ee_pos`` or a ``self_collision`` of 7 is no rollout this repo writes); no finite value
    beyond LIMITS. RolloutError naming the file, the array and the step."""
    T = fields["t"].shape[0] if fields["t"].ndim == 1 else -1
    for key in (*ARRAY_KEYS, *(k for k in OPTIONAL_KEYS if k in fields)):
        a = fields[key]
        want = (T, COLUMNS[key]) if key in COLUMNS else (T,)
        if T < 1 or a.shape != want:
            shown = "(T,)" if key not in COLUMNS else f"(T, {COLUMNS[key]})"
            raise _damaged(path, f"{key} has shape {a.shape}, expected {shown} with the same "
                           f"T >= 1 as t {fields['t'].shape}")
        kind = "b" if key in FLAG_KEYS else "f"
        if a.dtype.kind != kind:
            raise _damaged(path, f"{key} has dtype {a.dtype}, expected "
                           f"{'bool' if key in FLAG_KEYS else 'numbers (floating point)'}")
        if key in LIMITS:
            limit, words = LIMITS[key]
            with np.errstate(invalid="ignore"):
                beyond = np.isfinite(a) & (np.abs(a) > limit)
            if beyond.any():
                step = int(np.argwhere(beyond)[0][0])
                value = a.reshape(T, -1)[step][beyond.reshape(T, -1)[step]][0]
                raise _damaged(path, f"{key} holds {value:g} at step {step}, beyond {limit:g} "
                               f"{words}")


# How far a recorded time or target may sit from the one the meta implies: float rounding of
# the physics clock (2,500 additions of the timestep in 5 s) is ~1e-13; a real mismatch (another
# seed, another time base, an edited target) is millimetres or more.
TIME_TOLERANCE_S = 1e-6
TARGET_TOLERANCE = {"target_pos": 1e-6, "target_vel": 1e-5, "target_acc": 1e-3}


def check_against_meta(fields: dict[str, np.ndarray], meta: dict, path: Path) -> None:
    """The rows and times the meta promises, and the target of the meta's seed: at most
    duration / dt rows (fewer only when the episode ended early: metrics charges those), ``t``
    the end of each control step (k * dt), and target_pos/vel/acc the seed's trajectory
    (trajectory.sample(seed, shape).at(t)), so a file cannot be scored over other times,
    another seed's target, or a target moved onto the tip. The last row of a failed episode
    is not checked (MuJoCo resets an unstable simulation's clock)."""
    dt, duration = float(meta["dt"]), float(meta["duration"])
    expected = int(round(duration / dt))
    T = len(fields["t"])
    if T > expected:
        raise _damaged(path, f"{T} rows, but its meta says {duration:g} s at {dt:g} s = "
                       f"{expected} steps")
    n = T - 1 if meta.get("failure") else T
    times = dt * np.arange(1, n + 1)
    t = np.asarray(fields["t"][:n], dtype=float)
    with np.errstate(invalid="ignore"):
        off = np.isfinite(t) & (np.abs(t - times) > TIME_TOLERANCE_S)
    if off.any():
        k = int(np.argmax(off))
        raise _damaged(path, f"t is {t[k]:g} s at step {k}, but step {k} of its meta's {dt:g} s "
                       f"steps ends at {times[k]:g} s")
    if n == 0:
        return
    want = dict(zip(("target_pos", "target_vel", "target_acc"),
                    trajectory.sample(int(meta["seed"]), meta["shape"]).at(times), strict=True))
    for key, tol in TARGET_TOLERANCE.items():
        got = np.asarray(fields[key][:n], dtype=float)
        with np.errstate(invalid="ignore"):
            off = np.isfinite(got).all(axis=1) & (np.abs(got - want[key]).max(axis=1) > tol)
        if off.any():
            k = int(np.argmax(off))
            raise _damaged(path, f"{key} at step {k} is not seed {meta['seed']}'s "
                           f"{meta['shape']} trajectory (off by "
                           f"{np.abs(got[k] - want[key][k]).max():.3g}); the file was edited "
                           "or holds another seed's episode")


def load(path: Path) -> Rollout:
    """Read and check a rollout file: every array's size is bounded before it is decompressed,
    shapes, dtypes, meta and physical ranges are checked; any flaw is one RolloutError line."""
    path = Path(path)
    try:
        with _open_checked(path) as z:
            names = set(z.namelist())
            missing = [k for k in (*ARRAY_KEYS, "meta") if f"{k}.npy" not in names]
            if missing:
                raise RolloutError(f"{path}: not a rollout file, missing {', '.join(missing)}")
            meta = _read_meta(z, path)
            fields = {k: _read_array(z, path, k, MAX_ARRAY_BYTES) for k in ARRAY_KEYS}
            fields.update({k: _read_array(z, path, k, MAX_ARRAY_BYTES) for k in OPTIONAL_KEYS
                           if f"{k}.npy" in names})
    except RolloutError:
        raise
    except _READ_ERRORS as exc:
        raise RolloutError(f"{path}: cannot read rollout ({type(exc).__name__}: {exc}); the file "
                           "is damaged or truncated, write it again") from None
    check_meta(meta, path)
    check_arrays(fields, path)
    check_against_meta(fields, meta, path)
    return Rollout(**fields, meta=meta)


def read_meta(path: Path) -> dict:
    """A rollout file's metadata alone (decompresses only that member, bounded), checked."""
    path = Path(path)
    try:
        with _open_checked(path) as z:
            meta = _read_meta(z, path)
    except RolloutError:
        raise
    except _READ_ERRORS as exc:
        raise RolloutError(f"{path}: cannot read rollout ({type(exc).__name__}: {exc})") from None
    check_meta(meta, path)
    return meta


def list_prefixes(root: Path = ROLLOUT_DIR) -> list[str]:
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if p.is_dir() and any(p.glob("seed_*.npz")))


def load_prefix(prefix: str, root: Path = ROLLOUT_DIR) -> dict[int, Rollout]:
    """All rollouts under a prefix, keyed by seed. A missing or empty prefix is a clear error."""
    folder = Path(root) / prefix
    files = sorted(folder.glob("seed_*.npz")) if folder.is_dir() else []
    if not files:
        existing = list_prefixes(root)
        hint = ", ".join(existing) if existing else "none (run ikpd.py or eval.py with --prefix)"
        raise NoRollouts(f"no rollouts under {folder}/; prefixes that exist: {hint}")
    out: dict[int, Rollout] = {}
    for f in files:
        r = load(f)
        # One file per seed, named by it: a file relabelled or copied under another name would
        # otherwise replace (or be replaced by) the seed's own, silently.
        if f.name != rollout_path(prefix, r.seed, root).name:
            raise _damaged(f, f"its meta says seed {r.seed}, so it should be named "
                           f"{rollout_path(prefix, r.seed, root).name}")
        out[r.seed] = r
    return out


def iter_record(config, act_fn, seeds, shapes=None, meta: dict | None = None,
                nthread: int = 0, batch_size: int = 256) -> Iterator[Rollout]:
    """Play one episode per trajectory seed, ``batch_size`` arms at a time, and yield each
    recorded episode as soon as its batch ends: the one code path every controller,
    evaluation and rollout set uses. Memory stays that of one batch however many seeds.

    ``act_fn(obs, task) -> actions`` decides each step for all arms ((N, obs) -> (N, 3));
    ``config`` is an env.EnvConfig (or its dict). Slot i's generator is seeded with its
    trajectory seed, as ``env.reset(seed=traj_seed)`` seeds the single env, so an episode is
    the same whether it is played alone, in a batch, or through ``record``.
    """
    from .config import as_config
    from .task import LeadTask

    config = as_config(config, {})
    seeds = [int(s) for s in seeds]
    shapes = [None] * len(seeds) if shapes is None else list(shapes)
    task = None
    for start in range(0, len(seeds), batch_size):
        chunk, chunk_shapes = seeds[start:start + batch_size], shapes[start:start + batch_size]
        if task is None or task.n != len(chunk):
            task = LeadTask(config, len(chunk), nthread=nthread)
        task.rngs = [np.random.default_rng(s) for s in chunk]
        obs = task.reset(None, chunk, chunk_shapes)
        yield from _play(task, obs, act_fn, meta)


def record_many(config, act_fn, seeds, shapes=None, meta: dict | None = None,
                nthread: int = 0, batch_size: int = 256) -> list[Rollout]:
    """iter_record, all episodes as a list."""
    return list(iter_record(config, act_fn, seeds, shapes, meta, nthread, batch_size))


def record(env, act_fn, traj_seed: int, shape: str | None = None, meta: dict | None = None,
           on_step=None) -> Rollout:
    """One episode of a single PandaLeadEnv (the viewer and videos use it; ``on_step(env)`` is
    called after each step, e.g. to render). Same episode as ``record_many`` on this seed."""
    options = {"traj_seed": int(traj_seed)}
    if shape is not None:
        options["shape"] = shape
    env = env.unwrapped
    obs, _ = env.reset(seed=int(traj_seed), options=options)
    hook = None if on_step is None else (lambda _task: on_step(env))
    return _play(env.task, obs[None], act_fn, meta, hook)[0]


def _play(task, obs, act_fn, meta, on_step=None) -> list[Rollout]:
    """Step every slot of a freshly reset task until each episode ends; one Rollout per slot."""
    core, n = task.core, task.n
    rows: dict[str, list] = {k: [] for k in (*ARRAY_KEYS, *OPTIONAL_KEYS)}
    end = np.full(n, -1)
    failure: list[str | None] = [None] * n
    returns = np.zeros(n)
    k = 0
    while (end < 0).any():
        obs, reward, terminated, truncated, info = task.step(act_fn(obs, task))
        pos, vel, acc = core.target()
        live = end < 0
        returns[live] += reward[live]
        rows["t"].append(core.time.copy())
        rows["ee_pos"].append(core.tip_pos.copy())
        rows["target_pos"].append(pos)
        rows["target_vel"].append(vel)
        rows["target_acc"].append(acc)
        rows["lead"].append(info["lead"].copy())
        rows["qpos"].append(core.qpos.copy())
        rows["qvel"].append(core.qvel.copy())
        rows["q_goal"].append(core.q_goal.copy())
        rows["self_collision"].append(info["self_collision"].copy())
        rows["collision_depth"].append(info["collision_depth"].copy())
        rows["reachable"].append(info["reachable"].copy())
        if on_step is not None:
            on_step(task)
        for i in np.flatnonzero(live & (terminated | truncated)):
            end[i] = k + 1
            if terminated[i]:
                failure[i] = failure_of(info, i, True)
        k += 1
    stacked = {key: np.stack(v, axis=1) for key, v in rows.items()}  # (N, T, ...)
    stacked["self_collision"] = stacked["self_collision"].astype(bool)
    stacked["reachable"] = stacked["reachable"].astype(bool)
    config = task.config.to_dict()
    out = []
    for i in range(n):
        full_meta = {
            "seed": int(task.traj_seeds[i]), "shape": task.shapes[i], "dt": task.dt,
            "duration": round(task.config.episode_steps * task.dt, 6), "env": config,
            "failure": failure[i], "return": float(returns[i]), **(meta or {}),
        }
        out.append(Rollout(**{key: v[i, :end[i]] for key, v in stacked.items()}, meta=full_meta))
    return out


def identity(meta: dict) -> tuple:
    """What makes two rollouts the same controller: its name, its model's hash (not the path
    it was given by), its settings (the analytic lead's tau, the oracle's, an online
    correction's: panda_lead/online.py) and the env it ran on, less the episode length. The
    rollout writer and metrics.py both use this rule."""
    from .config import EnvConfig

    env = meta.get("env") or {}
    try:
        env = EnvConfig.from_dict(env).to_dict()  # older files wrote some settings flat
    except (UserError, TypeError):
        pass
    env = {**env, "episode_steps": None} if isinstance(env, dict) else env
    return (meta.get("controller"), meta.get("model_sha256"),
            json.dumps(meta.get("tau")), json.dumps(meta.get("ilc"), sort_keys=True),
            json.dumps(meta.get("online"), sort_keys=True),
            json.dumps(env, sort_keys=True, default=str))
