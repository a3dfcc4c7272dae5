"""Saving and loading trained models with their sidecars, without ever unpickling.

A model ``X.zip`` always travels with ``X.json``: the full env config (so the env can be rebuilt
exactly: observation features, reward weights, action scale, rates, noise), the training
config, timesteps, wall time, code commit, the SHA-256 of the zip (``model_sha256``, which binds
the sidecar to this one file) and, for archived models, test-set metrics. Every write is atomic
(temporary name, then rename).

Why not ``PPO.load``: SB3's zip stores pickled objects (its ``data`` member holds cloudpickle
strings), so loading a file from elsewhere with ``PPO.load`` runs whatever code it carries
(SB3 issues #1852, #2281). Here the policy is rebuilt from the sidecar (architecture, spaces
from the env config) and only tensors are read from the zip, with
``torch.load(..., weights_only=True)``; the ``data`` member is never read. The zip itself is
still SB3's format, written by ``model.save``.
"""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import zipfile
from pathlib import Path

from .atomicio import atomic_write
from .config import OBS_FEATURES, EnvConfig
from .errors import UserError

ARCHIVE_DIR = Path("archive")
PHYSICS_HZ, CONTROL_HZ = 500, 100
# The policy's architecture when a sidecar does not say (every model this repo trained).
DEFAULT_POLICY = {"net_arch": [64, 64], "activation_fn": "tanh", "log_std_init": 0.0}
ACTIVATIONS = ("tanh", "relu")
# The observation layouts of the reference ladder (training.PRESETS builds on them); a model
# without a sidecar is matched against them to say which features it probably takes.
OBS_12 = ("ee_pos", "ee_vel", "target_pos", "target_vel")
OBS_15 = OBS_12 + ("target_acc",)
OBS_29 = OBS_15 + ("joint_pos", "joint_vel")


class ModelError(UserError):
    """A user-facing problem with a model file or its sidecar."""


def sidecar_path(model_path: Path) -> Path:
    return Path(model_path).with_suffix(".json")


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             cwd=Path(__file__).parent, timeout=5)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, cwd=Path(__file__).parent,
                               timeout=5).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "") if out.returncode == 0 else "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


def write_json_atomic(path: Path, data: dict) -> None:
    with atomic_write(path, ".tmp.json") as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, sort_keys=True, default=str)
        f.write("\n")


def policy_spec(model) -> dict:
    """The architecture a sidecar records, so that loading can rebuild the policy."""
    import torch

    kw = model.policy_kwargs
    act = kw.get("activation_fn", torch.nn.Tanh)
    return {"net_arch": list(kw.get("net_arch", DEFAULT_POLICY["net_arch"])),
            "activation_fn": act.__name__.lower(),
            "log_std_init": float(kw.get("log_std_init", 0.0))}


# A JSON member of the zip (SB3 ignores it) holding the env config the weights were trained
# for: a sidecar can be rewritten or swapped, but then it no longer matches this.
ENV_MEMBER = "lead_env_config.json"


def _add_env_member(zip_path, env_config: dict) -> None:
    with zipfile.ZipFile(zip_path, "a") as z:
        z.writestr(ENV_MEMBER, json.dumps(EnvConfig.from_dict(env_config).to_dict(),
                                          sort_keys=True))


def save_model(model, path: Path, sidecar: dict) -> Path:
    """Save an SB3 model and its sidecar atomically; the zip carries its env config too, and
    the sidecar (with the zip's hash) lands last, so a zip without a matching sidecar is never
    trusted."""
    path = Path(path).with_suffix(".zip")
    with atomic_write(path, ".tmp.zip") as tmp:
        model.save(tmp)
        _add_env_member(tmp, sidecar["env_config"])
    rates = {"physics_hz": PHYSICS_HZ, "control_hz": CONTROL_HZ}
    full = {**sidecar, "policy": policy_spec(model), "rates": rates,
            "commit": sidecar.get("commit") or git_commit(), "model_sha256": file_sha256(path)}
    write_json_atomic(sidecar_path(path), full)
    return path


def bind_sidecar(model_path: Path) -> None:
    """Write the zip's hash into its sidecar: only for a pair you trust (e.g. archive/ before
    sidecars carried hashes)."""
    side = read_sidecar(model_path)
    with zipfile.ZipFile(model_path) as z:
        has = ENV_MEMBER in z.namelist()
    if not has:
        with atomic_write(model_path, ".tmp.zip") as tmp:
            Path(tmp).write_bytes(Path(model_path).read_bytes())
            _add_env_member(tmp, side["env_config"])
    side["model_sha256"] = file_sha256(model_path)
    write_json_atomic(sidecar_path(model_path), side)


def read_sidecar(model_path: Path) -> dict:
    path = sidecar_path(model_path)
    if not path.is_file():
        raise ModelError(f"{model_path}: no sidecar {path.name} beside it, so its env cannot be "
                         "rebuilt" + _infer_hint(model_path))
    try:
        side = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: unreadable sidecar ({exc})") from None
    if not isinstance(side, dict) or not isinstance(side.get("env_config"), dict):
        raise ModelError(f"{path}: sidecar has no env_config")
    return side


def _read_tensors(model_path: Path, member: str, device: str = "cpu"):
    """One torch member of the zip, read as plain tensors: a pickle that would build any other
    object (run code) is refused by torch instead of executed."""
    import pickle

    import torch

    try:
        with zipfile.ZipFile(model_path) as z:
            raw = z.read(member)
        return torch.load(io.BytesIO(raw), map_location=device, weights_only=True)
    except KeyError:
        raise ModelError(f"{model_path}: cannot load model (no {member} in the zip)") from None
    except (OSError, zipfile.BadZipFile, EOFError, RuntimeError, pickle.UnpicklingError,
            ValueError, AttributeError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise ModelError(f"{model_path}: cannot load model ({member}: {type(exc).__name__}: "
                         f"{first[:200]})") from None


def _obs_dim_of(state: dict) -> int | None:
    for key in ("mlp_extractor.policy_net.0.weight", "action_net.weight"):
        w = state.get(key)
        if w is not None and getattr(w, "ndim", 0) == 2:
            return int(w.shape[1])
    return None


def _infer_hint(model_path: Path) -> str:
    try:
        dim = _obs_dim_of(_read_tensors(model_path, "policy.pth"))
    except ModelError:
        dim = None
    if dim is None:
        return "."
    known = {sum(OBS_FEATURES[x] for x in f): f for f in (OBS_12, OBS_15, OBS_29)}
    guess = known.get(dim)
    if guess:
        return (f". The model's observation is {dim}-D, which matches the features "
                f"{', '.join(guess)}; write a sidecar with that env_config (see README) to use it.")
    return f". The model's observation is {dim}-D."


def verify(model_path: str | Path) -> dict:
    """Check that a model file exists, is a zip and is the one its sidecar describes (SHA-256);
    returns the sidecar. Reads no model content."""
    model_path = Path(model_path)
    if not model_path.is_file():
        have = sorted(str(p) for p in ARCHIVE_DIR.glob("*.zip")) if ARCHIVE_DIR.is_dir() else []
        hint = f"; archived models: {', '.join(have)}" if have else "; the archive is empty"
        raise ModelError(f"model not found: {model_path}{hint}")
    if not zipfile.is_zipfile(model_path):
        raise ModelError(f"{model_path}: not a model zip (corrupt or truncated file)")
    side = read_sidecar(model_path)
    want = side.get("model_sha256")
    if not want:
        raise ModelError(f"{sidecar_path(model_path)}: no model_sha256, so nothing says the "
                         "sidecar belongs to this model; if you trust the pair, bind it with "
                         f"`uv run python -c \"import models; models.bind_sidecar('{model_path}')\"`")
    if file_sha256(model_path) != want:
        raise ModelError(f"{model_path}: the file's SHA-256 differs from its sidecar's "
                         "model_sha256; the sidecar does not belong to this model (or the file "
                         "changed)")
    return side


def policy_kwargs_of(side: dict) -> dict:
    """The policy's constructor arguments, from the sidecar (older sidecars: train_config)."""
    import torch

    spec = dict(DEFAULT_POLICY)
    train = side.get("train_config") or {}
    for k in ("net_arch", "log_std_init"):
        if k in train:
            spec[k] = train[k]
    spec.update(side.get("policy") or {})
    if spec["activation_fn"] not in ACTIVATIONS:
        raise ModelError(f"unknown activation {spec['activation_fn']!r} in the sidecar")
    act = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[spec["activation_fn"]]
    return {"net_arch": [int(x) for x in spec["net_arch"]], "activation_fn": act,
            "log_std_init": float(spec["log_std_init"])}


def spaces_for(env_config: EnvConfig):
    """(observation space, action space) of PandaLead-v0 with this config."""
    import numpy as np
    from gymnasium import spaces

    from .core import N_JOINTS

    dim = sum(OBS_FEATURES[f] for f in env_config.obs_features)
    actions = 3 if env_config.action == "lead" else N_JOINTS  # a lead, or a joint residual
    return (spaces.Box(-np.inf, np.inf, (dim,), np.float32),
            spaces.Box(-1.0, 1.0, (actions,), np.float32))


def load_policy(model_path: str | Path, device: str = "cpu"):
    """-> (policy, env config dict, sidecar). The policy (an SB3 ``ActorCriticPolicy``, with
    ``predict(obs, deterministic)``) is rebuilt from the sidecar and gets only the zip's
    weights. Never unpickles; every problem is one ModelError line."""
    from stable_baselines3.common.policies import ActorCriticPolicy

    model_path = Path(model_path)
    side = verify(model_path)
    try:
        env_config = EnvConfig.from_dict(side["env_config"])
    except UserError as exc:
        raise ModelError(f"{sidecar_path(model_path)}: {exc}") from None
    try:
        with zipfile.ZipFile(model_path) as z:
            stored = EnvConfig.from_dict(json.loads(z.read(ENV_MEMBER)))
    except KeyError:
        raise ModelError(f"{model_path}: the zip holds no {ENV_MEMBER}, so its env config cannot "
                         "be checked against the sidecar (saved before models carried it; "
                         "bind a pair you trust with models.bind_sidecar)") from None
    except (OSError, zipfile.BadZipFile, ValueError, UserError, TypeError) as exc:
        raise ModelError(f"{model_path}: cannot load model ({ENV_MEMBER}: {exc})") from None
    if stored != env_config:
        diff = [k for k in stored.to_dict() if getattr(stored, k) != getattr(env_config, k)]
        raise ModelError(f"{model_path}: the sidecar's env config differs from the one the model "
                         f"was trained with ({', '.join(diff)}: sidecar "
                         f"{getattr(env_config, diff[0])!r}, model {getattr(stored, diff[0])!r}); "
                         "the sidecar does not belong to this model")
    state = _read_tensors(model_path, "policy.pth", device)
    if not isinstance(state, dict):
        raise ModelError(f"{model_path}: cannot load model (policy.pth holds no state dict)")
    obs_space, act_space = spaces_for(env_config)
    found, expected = _obs_dim_of(state), obs_space.shape[0]
    if found is not None and found != expected:
        raise ModelError(
            f"{model_path}: the model takes a {found}-D observation but its sidecar's features "
            f"({', '.join(env_config.obs_features)}) make {expected}-D; the sidecar does not "
            "belong to this model")
    policy = ActorCriticPolicy(obs_space, act_space, lambda _: 0.0, **policy_kwargs_of(side))
    try:
        policy.load_state_dict(state)
    except RuntimeError as exc:
        raise ModelError(f"{model_path}: the weights do not fit the sidecar's architecture "
                         f"({str(exc).splitlines()[0]})") from None
    policy.to(device).set_training_mode(False)
    return policy, env_config.to_dict(), side


def load_training_state(model, model_path: Path) -> None:
    """Put a checkpoint's policy and optimizer tensors into a freshly built PPO (same config)."""
    state = _read_tensors(model_path, "policy.pth", model.device)
    try:
        model.policy.load_state_dict(state)
        model.policy.optimizer.load_state_dict(
            _read_tensors(model_path, "policy.optimizer.pth", model.device))
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        raise ModelError(f"{model_path}: the checkpoint does not fit the run's config "
                         f"({str(exc).splitlines()[0]})") from None


def newest_archived() -> Path | None:
    models = sorted(ARCHIVE_DIR.glob("*.zip"), key=lambda p: p.stat().st_mtime)
    return models[-1] if models else None
