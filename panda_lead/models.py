"""Saving and loading trained models with their sidecars, without ever unpickling.

A model ``X.zip`` is SB3's format plus one JSON member, ``panda_lead_sidecar.json``: the
sidecar, i.e. everything that decides what the weights do and what they were: the full env
config (observation features, reward weights, action scale, noise, latency, IK), the policy's
architecture, the rates it was trained at, the training config, timesteps, wall time, code
commit and, for archived models, test metrics. Since the zip's SHA-256 covers that member, no
setting that decides a number can be edited without changing the model's hash, which every
rollout records. ``X.json`` beside it is the same sidecar plus ``model_sha256``, for people and
tools to read; a load checks that it is exactly what the zip carries.

Why not ``PPO.load``: SB3's zip stores pickled objects (its ``data`` member holds cloudpickle
strings), so loading a file from elsewhere with ``PPO.load`` runs whatever code it carries
(SB3 issues #1852, #2281). Here the policy is rebuilt from the sidecar and only tensors are
read from the zip, with ``torch.load(..., weights_only=True)``; ``data`` is never unpickled.
Every member is read with a size bound, so a zip bomb costs nothing but one error line.

Writing a pair (`write_pair`): the zip and the JSON are written to temporary names, then the
JSON is renamed into place, then the zip. Whatever moment a kill or a full disk strikes, the
previous zip is intact until the new one replaces it whole, and a zip whose JSON does not
match can always be restored from the sidecar the zip itself carries (`restore_sidecar`,
``eval.py --restore-sidecar``).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import subprocess
import zipfile
from contextlib import contextmanager
from pathlib import Path

from .atomicio import atomic_write, file_lock
from .config import OBS_12, OBS_15, OBS_29, OBS_FEATURES, EnvConfig
from .errors import UserError
from .paths import shipped
from .roles import HEADLINE

ARCHIVE_DIR = Path("archive")  # where train.py --archive writes, in the working folder
# The headline model (roles.py): what eval.py runs when no --model is given (named, not the
# newest file: git keeps no modification times).
DEFAULT_MODEL = HEADLINE
SIDECAR_MEMBER = "panda_lead_sidecar.json"
ACTIVATIONS = ("tanh", "relu")
# Size bounds, checked before anything is read: far above any real model of this repo (a
# 64x64 policy.pth is 40 kB), far below what would hurt a machine.
MAX_ZIP_BYTES = 512 * 2**20
MAX_TENSOR_MEMBER_BYTES = 256 * 2**20
MAX_JSON_BYTES = 2**20
MAX_LAYERS, MAX_WIDTH = 8, 4096


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
    here = Path(__file__).parent
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             cwd=here, timeout=5)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, cwd=here, timeout=5).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "") if out.returncode == 0 else "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


def cpu_name() -> str:
    """The CPU's model name ("?" where unknown). A training run's digits depend on it (torch's
    and MuJoCo's kernels are picked by CPU: results/studies/rederive/rederive.md), so sidecars
    record it."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "?"  # e.g. aarch64: no model name


def write_json_atomic(path: Path, data: dict) -> None:
    with atomic_write(path, ".tmp.json") as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, sort_keys=True, default=str)
        f.write("\n")


def _canonical(side: dict) -> dict:
    """A sidecar as JSON would give it back (tuples as lists, keys as str)."""
    return json.loads(json.dumps(side, sort_keys=True, default=str))


# --- reading, bounded ------------------------------------------------------------------------
def read_member(model_path: Path, member: str, limit: int) -> bytes:
    """One member of a zip, refused (ModelError) if it would expand beyond ``limit`` bytes: the
    declared size is checked first, and the read itself stops at the bound whatever the
    header claims."""
    try:
        with zipfile.ZipFile(model_path) as z:
            info = z.getinfo(member)
            if info.file_size > limit:
                raise ModelError(f"{model_path}: cannot load model ({member} would expand to "
                                 f"{info.file_size:,} bytes, more than the {limit:,} allowed)")
            with z.open(info) as f:
                data = f.read(limit + 1)
    except KeyError:
        raise ModelError(f"{model_path}: cannot load model (no {member} in the zip)") from None
    except (OSError, zipfile.BadZipFile, EOFError, ValueError, RuntimeError) as exc:
        raise ModelError(f"{model_path}: cannot load model ({member}: {type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    if len(data) > limit:
        raise ModelError(f"{model_path}: cannot load model ({member} expands beyond "
                         f"{limit:,} bytes)")
    return data


def _read_json_member(model_path: Path, member: str) -> dict:
    try:
        data = json.loads(read_member(model_path, member, MAX_JSON_BYTES))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{model_path}: cannot load model ({member}: {exc})") from None
    if not isinstance(data, dict):
        raise ModelError(f"{model_path}: cannot load model ({member} is not a JSON object)")
    return data


def _read_tensors(model_path: Path, member: str, device: str = "cpu"):
    """One torch member of the zip, read as plain tensors: a pickle that would build any other
    object (run code) is refused by torch instead of executed."""
    import pickle

    import torch

    raw = read_member(model_path, member, MAX_TENSOR_MEMBER_BYTES)
    try:
        return torch.load(io.BytesIO(raw), map_location=device, weights_only=True)
    except (OSError, EOFError, RuntimeError, pickle.UnpicklingError, ValueError,
            AttributeError, TypeError, zipfile.BadZipFile) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise ModelError(f"{model_path}: cannot load model ({member}: {type(exc).__name__}: "
                         f"{first[:200]})") from None


def read_sidecar(model_path: Path) -> dict:
    """The JSON beside a model, read with a size bound; ModelError if missing or unreadable."""
    path = sidecar_path(model_path)
    if not path.is_file():
        raise ModelError(f"{model_path}: no sidecar {path.name} beside it, so its env cannot be "
                         "rebuilt" + _infer_hint(model_path))
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise ModelError(f"{path}: sidecar larger than {MAX_JSON_BYTES:,} bytes")
        side = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: unreadable sidecar ({exc})") from None
    if not isinstance(side, dict) or not isinstance(side.get("env_config"), dict):
        raise ModelError(f"{path}: sidecar has no env_config")
    return side


# --- the sidecar's schema --------------------------------------------------------------------
def rates() -> dict:
    """The rates a model is trained and run at, derived from the MJCF (core.control_dt)."""
    from .core import CONTROL_SUBSTEPS, control_dt

    return {"physics_hz": round(CONTROL_SUBSTEPS / control_dt(), 9),
            "control_hz": round(1.0 / control_dt(), 9)}


def check_policy_spec(spec, where: str) -> dict:
    """A sidecar's policy block, validated with bounds (a 200,000-wide layer is refused
    before torch tries to allocate it)."""
    if not isinstance(spec, dict):
        raise ModelError(f"{where}: the sidecar has no policy block (the architecture)")
    arch = spec.get("net_arch")
    nets = arch.values() if isinstance(arch, dict) else [arch]
    if isinstance(arch, dict) and set(arch) != {"pi", "vf"}:
        nets = [None]
    for net in nets:
        ok = isinstance(net, list) and 1 <= len(net) <= MAX_LAYERS and all(
            type(n) is int and 1 <= n <= MAX_WIDTH for n in net)
        if not ok:
            raise ModelError(f"{where}: policy net_arch must be 1-{MAX_LAYERS} layer widths of "
                             f"1-{MAX_WIDTH} (or pi/vf lists of them), got {arch!r}")
    if spec.get("activation_fn") not in ACTIVATIONS:
        raise ModelError(f"{where}: unknown activation {spec.get('activation_fn')!r} in the "
                         f"sidecar (valid: {', '.join(ACTIVATIONS)})")
    log_std = spec.get("log_std_init")
    if isinstance(log_std, bool) or not isinstance(log_std, int | float) or not math.isfinite(
            log_std) or abs(log_std) > 20:
        raise ModelError(f"{where}: policy log_std_init must be a finite number, got {log_std!r}")
    if not isinstance(spec.get("use_sde", False), bool):
        raise ModelError(f"{where}: policy use_sde must be true or false, got "
                         f"{spec.get('use_sde')!r}")
    return spec


def check_sidecar(side: dict, where: str) -> EnvConfig:
    """Validate everything a load relies on; returns the env config. ModelError on any flaw."""
    try:
        env_config = EnvConfig.from_dict(side["env_config"])
    except (UserError, TypeError, KeyError) as exc:
        raise ModelError(f"{where}: {exc}") from None
    check_policy_spec(side.get("policy"), where)
    steps = side.get("timesteps", 0)
    if type(steps) is not int or steps < 0:
        raise ModelError(f"{where}: timesteps must be an integer >= 0, got {steps!r}")
    if side.get("rates") != rates():
        raise ModelError(f"{where}: trained at rates {side.get('rates')!r}, but this repo's MJCF "
                         f"runs at {rates()}; the policy would see another plant")
    return env_config


# --- writing ---------------------------------------------------------------------------------
def policy_spec(model) -> dict:
    """The architecture a sidecar records, so that loading can rebuild the policy."""
    import torch

    kw = model.policy_kwargs
    act = kw.get("activation_fn", torch.nn.Tanh)
    arch = kw.get("net_arch", [64, 64])
    spec = {"net_arch": dict(arch) if isinstance(arch, dict) else list(arch),
            "activation_fn": act.__name__.lower(),
            "log_std_init": float(kw.get("log_std_init", 0.0))}
    if getattr(model, "use_sde", False):  # (recorded only when on: older sidecars stay valid)
        spec["use_sde"] = True
    return spec


def write_pair(path: Path, write_zip, sidecar: dict) -> dict:
    """Write ``path`` (a zip made by ``write_zip(tmp_path)``, plus the sidecar member) and its
    JSON, as a pair (see the module docstring for the order); returns the JSON's content."""
    path = Path(path).with_suffix(".zip")
    side = _canonical({k: v for k, v in sidecar.items() if k != "model_sha256"})
    with atomic_write(path, ".tmp.zip") as tmp:
        write_zip(tmp)
        with zipfile.ZipFile(tmp, "a") as z:
            if SIDECAR_MEMBER in z.namelist():
                raise ValueError(f"{SIDECAR_MEMBER} already in the zip being written")
            z.writestr(SIDECAR_MEMBER, json.dumps(side, sort_keys=True))
        full = {**side, "model_sha256": file_sha256(tmp)}
        write_json_atomic(sidecar_path(path), full)  # the JSON lands first, the zip after it
    return full


def save_model(model, path: Path, sidecar: dict) -> Path:
    """Save an SB3 model with its sidecar (architecture, rates and commit added) as a pair."""
    full = {**sidecar, "policy": policy_spec(model), "rates": rates(),
            "commit": sidecar.get("commit") or git_commit()}
    write_pair(path, model.save, full)
    return Path(path).with_suffix(".zip")


def _copy_members(src: Path, skip: tuple[str, ...] = (SIDECAR_MEMBER,)):
    def write(tmp: str) -> None:
        with zipfile.ZipFile(src) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                if info.filename not in skip:
                    zout.writestr(info, read_member(src, info.filename, MAX_TENSOR_MEMBER_BYTES))
    return write


def copy_with_sidecar(src: Path, dst: Path, extra: dict) -> dict:
    """dst = src's members with src's (verified) sidecar plus ``extra``, written as a pair."""
    side = verify(src)
    return write_pair(dst, _copy_members(Path(src)), {**side, **extra})


def bind_sidecar(model_path: Path) -> None:
    """Make the zip carry the JSON beside it (and the JSON its new hash): only for a pair you
    trust, e.g. one edited by hand on purpose. Validation happens at load time."""
    side = read_sidecar(model_path)
    tmp_copy = Path(model_path).with_name(f".{Path(model_path).stem}.bind.zip")
    tmp_copy.write_bytes(Path(model_path).read_bytes())
    try:
        write_pair(model_path, _copy_members(tmp_copy), side)
    finally:
        tmp_copy.unlink(missing_ok=True)


LEGACY_ENV_MEMBER = "lead_env_config.json"


def upgrade_legacy(model_path: Path) -> bool:
    """A model saved before zips carried their sidecar (0.1: the zip carried only its env
    config, as lead_env_config.json) gets its sidecar embedded, if and only if the pair is
    intact: the JSON's model_sha256 matches the zip and the zip's env config matches the
    JSON's. Returns whether it upgraded anything; a damaged pair is a ModelError."""
    model_path = Path(model_path)
    _check_zip_file(model_path)
    with zipfile.ZipFile(model_path) as z:
        names = z.namelist()
    if SIDECAR_MEMBER in names:
        return False
    side = read_sidecar(model_path)
    if side.get("model_sha256") != file_sha256(model_path) or LEGACY_ENV_MEMBER not in names:
        raise ModelError(f"{model_path}: an older model whose sidecar is not bound to it; "
                         "adopt it instead (`uv run eval.py --adopt`)")
    stored = _read_json_member(model_path, LEGACY_ENV_MEMBER)
    if EnvConfig.from_dict(stored) != EnvConfig.from_dict(side["env_config"]):
        raise ModelError(f"{model_path}: its sidecar's env config differs from the one it "
                         "carries")
    if "policy" not in side:  # 0.1 sidecars before the policy block: the architecture trained
        train = side.get("train_config") or {}
        side["policy"] = {"net_arch": train.get("net_arch", [64, 64]), "activation_fn": "tanh",
                          "log_std_init": float(train.get("log_std_init", 0.0))}
    side.setdefault("rates", rates())
    tmp_copy = model_path.with_name(f".{model_path.stem}.legacy.zip")
    tmp_copy.write_bytes(model_path.read_bytes())
    try:
        write_pair(model_path, _copy_members(tmp_copy, (SIDECAR_MEMBER, LEGACY_ENV_MEMBER)), side)
    finally:
        tmp_copy.unlink(missing_ok=True)
    return True


def restore_sidecar(model_path: Path) -> Path:
    """Rewrite X.json from the sidecar the zip X.zip carries (after an interrupted write, or a
    JSON edited or lost)."""
    model_path = Path(model_path)
    _check_zip_file(model_path)
    side = _read_json_member(model_path, SIDECAR_MEMBER)
    check_sidecar(side, str(model_path))
    write_json_atomic(sidecar_path(model_path), {**side, "model_sha256": file_sha256(model_path)})
    return sidecar_path(model_path)


@contextmanager
def archive_lock(zip_path: Path):
    """Hold archive/.NAME.lock: one process at a time checks and writes archive/NAME."""
    zip_path = Path(zip_path)
    with file_lock(zip_path.parent / f".{zip_path.stem}.lock", f"the archive name {zip_path.stem}"):
        yield


# --- verifying and loading -------------------------------------------------------------------
def _check_zip_file(model_path: Path) -> None:
    if not model_path.is_file():
        raise ModelError(f"model not found: {model_path}{_archive_hint()}")
    if model_path.stat().st_size > MAX_ZIP_BYTES:
        raise ModelError(f"{model_path}: larger than {MAX_ZIP_BYTES // 2**20} MB; not a model "
                         "of this repo")
    if not zipfile.is_zipfile(model_path):
        raise ModelError(f"{model_path}: not a model zip (corrupt or truncated file)")


def verify(model_path: str | Path) -> dict:
    """Check that a model file exists, is a zip, is the one its JSON names (SHA-256), carries
    its sidecar, and that the JSON says exactly what the zip carries; returns the sidecar.
    Reads no weights."""
    model_path = Path(model_path)
    _check_zip_file(model_path)
    side = read_sidecar(model_path)
    want = side.get("model_sha256")
    if not want:
        raise ModelError(f"{sidecar_path(model_path)}: no model_sha256, so nothing says the "
                         "sidecar belongs to this model; a model trained elsewhere is adopted "
                         "with `uv run eval.py --adopt MODEL.zip --name NAME`")
    restore = (f"if this is your model after an interrupted write, restore the sidecar it "
               f"carries with `uv run eval.py --model {model_path} --restore-sidecar`")
    if file_sha256(model_path) != want:
        raise ModelError(f"{model_path}: the file's SHA-256 differs from its sidecar's "
                         f"model_sha256; the sidecar does not belong to this model (or the file "
                         f"changed); {restore}")
    try:
        with zipfile.ZipFile(model_path) as z:
            carried = SIDECAR_MEMBER in z.namelist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise ModelError(f"{model_path}: not a model zip ({exc})") from None
    if not carried:
        raise ModelError(f"{model_path}: the zip carries no sidecar (saved before models "
                         "carried theirs); adopt it with `uv run eval.py --adopt "
                         f"{model_path} --name NAME`")
    inner = _read_json_member(model_path, SIDECAR_MEMBER)
    outer = {k: v for k, v in side.items() if k != "model_sha256"}
    if inner != outer:
        keys = sorted(k for k in set(inner) | set(outer) if inner.get(k) != outer.get(k))
        detail = _first_difference(inner, outer)
        raise ModelError(f"{sidecar_path(model_path)}: differs from the sidecar the model "
                         f"carries ({', '.join(keys)}{detail}); the JSON was edited or belongs "
                         f"to another model; {restore}")
    return side


def _first_difference(inner: dict, outer: dict) -> str:
    """': obs_features: sidecar [...], model [...]' for the first differing env setting."""
    a, b = inner.get("env_config", {}), outer.get("env_config", {})
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            return f"; {k}: sidecar {b.get(k)!r}, model {a.get(k)!r}"
    return ""


def pair_state(model_path: Path) -> str:
    """'absent', 'valid', or why archive/NAME is not a valid pair (for refusing an overwrite
    with the right words)."""
    model_path = Path(model_path)
    if not model_path.exists() and not sidecar_path(model_path).exists():
        return "absent"
    try:
        verify(model_path)
        return "valid"
    except ModelError as exc:
        return f"is not a valid model with its sidecar ({exc})"


def _obs_dim_of(state: dict) -> int | None:
    for key in ("mlp_extractor.policy_net.0.weight", "action_net.weight"):
        w = state.get(key)
        if w is not None and getattr(w, "ndim", 0) == 2:
            return int(w.shape[1])
    return None


def _infer_hint(model_path: Path) -> str:
    try:
        state = _read_tensors(model_path, "policy.pth")
        dim = _obs_dim_of(state) if isinstance(state, dict) else None
    except ModelError:
        dim = None
    if dim is None:
        return "."
    flags = obs_flags_for(dim)
    if flags:
        return (f". The model's observation is {dim}-D, what {flags} gives; adopt it with "
                f"`uv run eval.py --adopt {model_path} --name NAME {flags}` (docs/env.md).")
    return f". The model's observation is {dim}-D."


def obs_flags_for(dim: int) -> str | None:
    """The --env.* flags whose observation is ``dim``-D (a named feature set, stacked if need
    be), or None: the one hint for a model whose observation size does not fit."""
    known = {sum(OBS_FEATURES[f] for f in feats): feats for feats in (OBS_12, OBS_15, OBS_29)}
    for stack in range(1, 17):
        if dim % stack == 0 and dim // stack in known:
            feats = known[dim // stack]
            return f"--env.obs-features {' '.join(feats)}" + (
                f" --env.obs-stack {stack}" if stack > 1 else "")
    return None


def _archive_hint() -> str:
    have = sorted({p.name for d in (ARCHIVE_DIR, shipped("archive")) if d.is_dir()
                   for p in d.glob("*.zip")})
    return f"; archived models: {', '.join(have)}" if have else "; the archive is empty"


def archived(name: str) -> Path:
    """archive/NAME.zip: in the working folder's archive/, else the archive shipped with the
    package (the repository's, or a wheel's copy), so a card's snippet runs from any folder."""
    for folder in (ARCHIVE_DIR, shipped("archive")):
        path = folder / f"{name}.zip"
        if path.is_file():
            return path
    raise ModelError(f"no archived model {name!r}{_archive_hint()}")


def policy_kwargs_of(side: dict) -> dict:
    """The policy's constructor arguments, from the sidecar's (validated) policy block."""
    import torch

    spec = check_policy_spec(side.get("policy"), "sidecar")
    act = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[spec["activation_fn"]]
    arch = spec["net_arch"]
    kwargs = {"net_arch": dict(arch) if isinstance(arch, dict) else list(arch),
              "activation_fn": act, "log_std_init": float(spec["log_std_init"])}
    if spec.get("use_sde"):  # (PPO passes its own use_sde to the policy: callers pop it)
        kwargs["use_sde"] = True
    return kwargs


def spaces_for(env_config: EnvConfig):
    """(observation space, action space) of PandaLead-v0 with this config."""
    import numpy as np
    from gymnasium import spaces

    from .config import action_dim

    dim = sum(OBS_FEATURES[f] for f in env_config.obs_features) * env_config.obs_stack
    return (spaces.Box(-np.inf, np.inf, (dim,), np.float32),
            spaces.Box(-1.0, 1.0, (action_dim(env_config.action),), np.float32))


class _NoOptimizer:
    """What SB3's policy gets instead of Adam when it is loaded to act, never to train: building
    any torch optimizer imports ``torch._dynamo`` (its ``add_param_group`` is wrapped to disable
    dynamo), ~6 s of every eval.py process on this machine. No optimizer state is ever read from
    an archived zip, so no number changes; ``policy.optimizer`` is this inert object."""

    def __init__(self, params, **kwargs) -> None:
        pass


def check_finite_weights(state: dict, model_path: Path) -> None:
    """ModelError naming the first tensor that holds NaN or inf: such a policy's first action
    would end an evaluation mid-episode (adopt refuses them the same way)."""
    import torch

    for key, value in state.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(
                torch.isfinite(value).all()):
            raise ModelError(f"{model_path}: cannot load model ({key} holds NaN or infinite "
                             "values)")


def load_policy(model_path: str | Path, device: str = "cpu"):
    """-> (policy, env config dict, sidecar). The policy (an SB3 ``ActorCriticPolicy``, with
    ``predict(obs, deterministic)``; no optimizer: see ``_NoOptimizer``) is rebuilt from the
    sidecar the zip carries and gets only the zip's weights. Never unpickles; every problem is
    one ModelError line."""
    from stable_baselines3.common.policies import ActorCriticPolicy

    model_path = Path(model_path)
    side = verify(model_path)
    env_config = check_sidecar(side, str(sidecar_path(model_path)))
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
    check_finite_weights(state, model_path)
    policy = ActorCriticPolicy(obs_space, act_space, lambda _: 0.0, **policy_kwargs_of(side),
                               optimizer_class=_NoOptimizer)
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
