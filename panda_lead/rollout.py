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
| meta            | ()     | str    | JSON: seed, shape, controller, model, duration, dt, env  |

Files are written atomically (temporary name, then ``os.replace``): an interrupted write never
leaves a half file that a later command would trust.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomicio import atomic_write
from .errors import UserError
from .task import failure_of

ROLLOUT_DIR = Path("rollouts")
ARRAY_KEYS = (
    "t", "ee_pos", "target_pos", "target_vel", "target_acc", "lead",
    "qpos", "qvel", "self_collision", "collision_depth", "reachable",
)


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


class RolloutError(UserError, ValueError):
    """A rollout file that cannot be read (truncated, not a rollout). Also a ValueError, for
    callers written before UserError."""


class NoRollouts(UserError, FileNotFoundError):
    """A prefix with no rollout files."""


def save(rollout: Rollout, path: Path) -> Path:
    """Write atomically: a temporary file in the same folder, then rename over the target. A
    full disk is one UserError line (atomicio), the previous file intact."""
    path = Path(path)
    arrays = {k: np.asarray(getattr(rollout, k)) for k in ARRAY_KEYS}
    arrays["meta"] = np.array(json.dumps(rollout.meta, sort_keys=True))
    with atomic_write(path, ".tmp.npz") as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


# What a damaged .npz raises inside numpy and zipfile (truncated, garbage, wrong member).
_READ_ERRORS = (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error,
                UnicodeDecodeError)


def load(path: Path) -> Rollout:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in (*ARRAY_KEYS, "meta") if k not in data.files]
            if missing:
                raise RolloutError(f"{path}: not a rollout file, missing {', '.join(missing)}")
            fields = {k: data[k] for k in ARRAY_KEYS}
            meta = json.loads(str(data["meta"]))
    except RolloutError:
        raise
    except _READ_ERRORS as exc:
        raise RolloutError(f"{path}: cannot read rollout ({type(exc).__name__}: {exc}); the file "
                           "is damaged or truncated, write it again") from None
    return Rollout(**fields, meta=meta)


def read_meta(path: Path) -> dict:
    """A rollout file's metadata alone (decompresses only that member)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            return json.loads(str(data["meta"]))
    except _READ_ERRORS as exc:
        raise RolloutError(f"{path}: cannot read rollout ({type(exc).__name__}: {exc})") from None


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
    rollouts = [load(f) for f in files]
    return {r.seed: r for r in rollouts}


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
    rows: dict[str, list] = {k: [] for k in ARRAY_KEYS}
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
    it was given by), its settings (the analytic lead's tau, the oracle's) and the env it ran
    on, less the episode length. The rollout writer and metrics.py both use this rule."""
    from .config import EnvConfig

    env = meta.get("env") or {}
    try:
        env = EnvConfig.from_dict(env).to_dict()  # older files wrote some settings flat
    except (UserError, TypeError):
        pass
    env = {**env, "episode_steps": None} if isinstance(env, dict) else env
    return (meta.get("controller"), meta.get("model_sha256"),
            json.dumps(meta.get("tau")), json.dumps(meta.get("ilc"), sort_keys=True),
            json.dumps(env, sort_keys=True, default=str))
