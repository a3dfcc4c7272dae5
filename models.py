"""Saving and loading trained models with their sidecars.

A model ``X.zip`` always travels with ``X.json``: the full env config (so the env can be rebuilt
exactly: observation features, reward weights, action scale, rates, noise), the training
config, timesteps, wall time, code commit and, for archived models, test-set metrics.
Every write is atomic (temporary name, then rename).
"""

from __future__ import annotations

import json
import subprocess
import zipfile
from pathlib import Path

from atomicio import atomic_write
from env import OBS_FEATURES, check_features

ARCHIVE_DIR = Path("archive")
PHYSICS_HZ, CONTROL_HZ = 500, 100


class ModelError(ValueError):
    """A user-facing problem with a model file or its sidecar."""


def sidecar_path(model_path: Path) -> Path:
    return Path(model_path).with_suffix(".json")


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


def save_model(model, path: Path, sidecar: dict) -> Path:
    """Save an SB3 model and its sidecar atomically; the sidecar lands last."""
    path = Path(path).with_suffix(".zip")
    with atomic_write(path, ".tmp.zip") as tmp:
        model.save(tmp)
    rates = {"physics_hz": PHYSICS_HZ, "control_hz": CONTROL_HZ}
    full = {**sidecar, "rates": rates, "commit": sidecar.get("commit") or git_commit()}
    write_json_atomic(sidecar_path(path), full)
    return path


def read_sidecar(model_path: Path) -> dict:
    path = sidecar_path(model_path)
    if not path.is_file():
        raise ModelError(f"{model_path}: no sidecar {path.name} beside it, so its env cannot be "
                         "rebuilt" + _infer_hint(model_path))
    try:
        side = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: unreadable sidecar ({exc})") from None
    if "env_config" not in side:
        raise ModelError(f"{path}: sidecar has no env_config")
    return side


def _model_obs_dim(model_path: Path) -> int | None:
    """The observation size stored in an SB3 zip, read without building a policy."""
    try:
        with zipfile.ZipFile(model_path) as z:
            data = json.loads(z.read("data"))
        shape = data["observation_space"]["_shape"]  # SB3 stores the space's attributes
        return int(shape[0])
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, TypeError):
        return None


def _infer_hint(model_path: Path) -> str:
    from presets import OBS_12, OBS_15, OBS_29

    dim = _model_obs_dim(model_path)
    if dim is None:
        return "."
    known = {sum(OBS_FEATURES[x] for x in f): f for f in (OBS_12, OBS_15, OBS_29)}
    guess = known.get(dim)
    if guess:
        return (f". The model's observation is {dim}-D, which matches the features "
                f"{', '.join(guess)}; write a sidecar with that env_config (see README) to use it.")
    return f". The model's observation is {dim}-D."


def load_policy(model_path: str | Path, device: str = "cpu"):
    """Load a PPO model and the env config that rebuilds its env. Raises ModelError clearly."""
    from stable_baselines3 import PPO

    model_path = Path(model_path)
    if not model_path.is_file():
        have = sorted(str(p) for p in ARCHIVE_DIR.glob("*.zip")) if ARCHIVE_DIR.is_dir() else []
        hint = f"; archived models: {', '.join(have)}" if have else "; the archive is empty"
        raise ModelError(f"model not found: {model_path}{hint}")
    if not zipfile.is_zipfile(model_path):
        raise ModelError(f"{model_path}: not a model zip (corrupt or truncated file)")
    side = read_sidecar(model_path)
    env_config = dict(side["env_config"])
    try:
        features = check_features(env_config.get("obs_features", ()))
    except ValueError as exc:
        raise ModelError(f"{sidecar_path(model_path)}: {exc}") from None
    try:
        model = PPO.load(model_path, device=device)
    except Exception as exc:  # SB3 raises many kinds on a damaged zip
        raise ModelError(f"{model_path}: cannot load model ({type(exc).__name__}: {exc})") from None
    expected = sum(OBS_FEATURES[f] for f in features)
    found = model.observation_space.shape
    if found != (expected,):
        raise ModelError(
            f"{model_path}: the model takes a {found[0]}-D observation but its sidecar's features "
            f"({', '.join(features)}) make {expected}-D; the sidecar does not belong to this model"
        )
    return model, env_config, side


def newest_archived() -> Path | None:
    models = sorted(ARCHIVE_DIR.glob("*.zip"), key=lambda p: p.stat().st_mtime)
    return models[-1] if models else None
