"""Adopting a model trained outside this repo: an SB3 PPO zip from RL Baselines3 Zoo, a
CleanRL-to-SB3 conversion or a user's own script becomes an archive entry (``archive/NAME.zip``
with its sidecar, ``NAME.json``, and a card, ``NAME.md``), like one train.py archives.

    uv run eval.py --adopt logs/ppo/PandaLead-v0_1/PandaLead-v0.zip --name zoo_v0
    uv run eval.py --adopt my_ppo.zip --name mine --env.obs-features ee_pos ee_vel target_pos target_vel

Nothing in the foreign file is unpickled. SB3's zip keeps its class parameters in the member
``data`` as JSON in which every object JSON cannot hold is a cloudpickle (``":serialized:"``,
base64) next to readable first-level fields (``":type:"``, a policy_kwargs' ``net_arch``, the
``repr`` of its ``activation_fn``, a Box's ``_shape`` and ``low``/``high``). Adoption reads
``data`` as plain JSON, never decodes a ``":serialized:"`` string, and reads the weights,
``policy.pth``, with ``torch.load(weights_only=True)``. From those it infers the policy
(net_arch from the weight shapes, checked against what ``data`` states; the activation;
``log_std_init``) and checks the spaces against the env config the model will be run with
(the defaults plus the ``--env.*`` settings given): observation size, action size, action
bounds [-1, 1]. The archived zip is then a fresh SB3 zip made here (a PPO built from that
spec, holding the adopted weights), so it carries no byte of the foreign pickles.

Refused, each in one line (``error: ...``, exit status 2, nothing written): a file that is not
an SB3 PPO zip; any policy but ``MlpPolicy`` (SB3's ``ActorCriticPolicy``) with a flat
feature extractor; gSDE (``use_sde``) or squashed outputs; an activation other than tanh and
relu; spaces that differ from the env's; observations normalised by VecNormalize, whose
running statistics live only in a pickle (RL Zoo's ``vecnormalize.pkl``) and without which
the weights see other inputs than they were trained on; an RL Zoo run whose ``env_kwargs``
differ from the env config given; an archive name in use (without ``--force``).

A model of this repo (its sidecar beside it) can be adopted too: the env config is then its
sidecar's plus the flags given, so that a deployment setting the model was not trained with
(``--env.noisy-lead-filter-hz 10``) becomes an archive entry of its own, with its card and
the source's sha256.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from .config import ACTIONS, EnvConfig
from .errors import UserError, check_plain_name
from .models import (
    ModelError,
    _check_zip_file,
    _read_tensors,
    archive_lock,
    check_policy_spec,
    file_sha256,
    obs_flags_for,
    read_member,
    spaces_for,
)

# SB3 keeps the last observations and the episode-info buffers in `data` (as base64 pickles
# that are never decoded here): a few MB for thousands of envs. Far above that is no model.
MAX_DATA_BYTES = 64 * 2**20
MAX_ZOO_FILE_BYTES = 2**20
POLICY_MODULE = "stable_baselines3.common.policies"
# policy_kwargs that do not change what the rebuilt policy computes (or are checked below).
HARMLESS_KWARGS = {"ortho_init", "optimizer_class", "optimizer_kwargs", "normalize_images",
                   "share_features_extractor", "full_std", "use_expln"}
ACTIVATION_RE = re.compile(r"<class 'torch\.nn\.modules\.activation\.(\w+)'>")
ACTIVATION_NAMES = {"Tanh": "tanh", "ReLU": "relu"}
FLATTEN_EXTRACTOR = "<class 'stable_baselines3.common.torch_layers.FlattenExtractor'>"
# The class parameters worth recording (plain numbers in `data`); the rest is training state.
HYPERPARAMS = ("n_envs", "n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda",
               "ent_coef", "vf_coef", "max_grad_norm", "learning_rate", "seed")
# Settings RL Zoo may pass to gym.make that are not EnvConfig fields (and decide no number).
NOT_CONFIG = ("render_mode", "width", "height")


@dataclass
class Foreign:
    """What a foreign zip holds, once checked: the policy spec, its weights and provenance."""

    path: Path
    spec: dict
    state: dict
    timesteps: int
    sb3_version: str
    hyperparams: dict = field(default_factory=dict)
    zoo_run: str | None = None  # the RL Zoo params folder beside the zip, if any


def _refuse(path: Path, why: str) -> ModelError:
    return ModelError(f"{path}: cannot adopt ({why})")


# --- the foreign zip's `data`, as plain JSON --------------------------------------------------
def read_data(path: Path) -> dict:
    """The zip's ``data`` member as JSON (``":serialized:"`` strings stay undecoded)."""
    import json

    raw = read_member(path, "data", MAX_DATA_BYTES)
    try:
        data = json.loads(raw)
    except RecursionError:  # thousands of nested brackets: no SB3 writes that
        raise _refuse(path, "its data member nests too deeply; not an SB3 zip") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _refuse(path, f"its data member is not JSON: {str(exc)[:120]}; not an SB3 zip") \
            from None
    if not isinstance(data, dict):
        raise _refuse(path, "its data member is not a JSON object; not an SB3 zip")
    return data


def _readable(entry) -> dict:
    """The readable fields of a data entry (a plain dict, or one SB3 could not hold as JSON)."""
    if not isinstance(entry, dict):
        return {}
    return {k: v for k, v in entry.items() if k not in (":type:", ":serialized:")}


def _policy_class(path: Path, data: dict) -> None:
    """Refuse anything but SB3's ActorCriticPolicy (what "MlpPolicy" names for PPO)."""
    cls = data.get("policy_class")
    if not isinstance(cls, dict):
        raise _refuse(path, "its data names no policy_class; not an SB3 zip")
    init = str(cls.get("__init__", ""))
    name = re.match(r"<function (\w+)\.__init__", init)
    name = name.group(1) if name else "an unnamed class"
    if cls.get("__module__") != POLICY_MODULE or name != "ActorCriticPolicy":
        where = cls.get("__module__", "?")
        raise _refuse(path, f"its policy is {name} from {where}; only MlpPolicy (SB3's "
                            "ActorCriticPolicy on a flat observation) is rebuilt here")
    if "clip_range" not in data or "n_epochs" not in data:
        raise _refuse(path, "its data has no clip_range or n_epochs, so it is not a PPO model "
                            "(only PPO is adopted)")
    if data.get("use_sde"):
        raise _refuse(path, "it was trained with gSDE (use_sde), whose noise and squashed "
                            "actions this repo does not rebuild; train with use_sde False")


def _policy_kwargs(path: Path, data: dict) -> dict:
    kwargs = data.get("policy_kwargs") or {}
    if not isinstance(kwargs, dict):
        raise _refuse(path, f"its policy_kwargs are {type(kwargs).__name__}, not a mapping")
    if ":serialized:" in kwargs and ":type:" in kwargs and "dict" not in str(kwargs[":type:"]):
        raise _refuse(path, f"its policy_kwargs are a {kwargs[':type:']}, not a dict")
    kwargs = _readable(kwargs)
    if kwargs.get("squash_output"):
        raise _refuse(path, "its policy squashes its output (squash_output), which this repo "
                            "does not rebuild")
    extractor = kwargs.get("features_extractor_class")
    if extractor is not None and extractor != FLATTEN_EXTRACTOR:
        raise _refuse(path, f"its features extractor is {extractor}; only the flat MLP input "
                            "(FlattenExtractor) is rebuilt")
    if kwargs.get("features_extractor_kwargs"):
        raise _refuse(path, "its policy_kwargs set features_extractor_kwargs; only the plain "
                            "FlattenExtractor is rebuilt")
    unknown = sorted(set(kwargs) - HARMLESS_KWARGS - {
        "net_arch", "activation_fn", "log_std_init", "squash_output", "features_extractor_class",
        "features_extractor_kwargs"})
    if unknown:
        raise _refuse(path, f"its policy_kwargs set {', '.join(unknown)}, which this repo does "
                            "not rebuild (net_arch, activation_fn and log_std_init are)")
    return kwargs


def _activation(path: Path, kwargs: dict) -> str:
    act = kwargs.get("activation_fn")
    if act is None:
        return "tanh"  # ActorCriticPolicy's default
    m = ACTIVATION_RE.fullmatch(str(act))
    if not m or m.group(1) not in ACTIVATION_NAMES:
        raise _refuse(path, f"its activation is {act}; only tanh and relu are rebuilt")
    return ACTIVATION_NAMES[m.group(1)]


# --- spaces -----------------------------------------------------------------------------------
def _numbers(text) -> list[float] | None:
    """The numbers of a numpy array's str ('[-1. -1. -1.]'), or None if it is not one (an
    abbreviated '...' array, anything else). Parsed, never evaluated."""
    if isinstance(text, int | float) and not isinstance(text, bool):
        return [float(text)]
    if isinstance(text, list):
        return [float(x) for x in text] if all(
            isinstance(x, int | float) and not isinstance(x, bool) for x in text) else None
    if not isinstance(text, str) or "..." in text:
        return None
    s = text.strip()
    if not (s.startswith("[") and s.endswith("]")) or "[" in s[1:-1] or "]" in s[1:-1]:
        return None
    try:
        return [float(x) for x in s[1:-1].split()]
    except ValueError:
        return None


def _box(path: Path, data: dict, key: str) -> tuple[int, dict]:
    space = data.get(key)
    kind = str(space.get(":type:", "")) if isinstance(space, dict) else ""
    if not re.search(r"\bgym(nasium)?\.spaces\.box\.Box\b", kind):
        raise _refuse(path, f"its {key} is {kind or 'missing'}; the env's is a Box")
    fields = _readable(space)
    shape = fields.get("_shape", fields.get("shape"))
    if not (isinstance(shape, list) and len(shape) == 1 and type(shape[0]) is int):
        raise _refuse(path, f"its {key} has shape {shape!r}; the env's is one flat vector")
    return shape[0], fields


def _hint_obs(dim: int) -> str:
    flags = obs_flags_for(dim)
    return f"; {dim}-D is what {flags} gives: add that if it was trained so" if flags else ""


def check_spaces(path: Path, data: dict, env_config: EnvConfig) -> tuple[int, int]:
    """The model's observation and action sizes, checked against the env config's."""
    obs_space, act_space = spaces_for(env_config)
    obs_dim, _ = _box(path, data, "observation_space")
    want_obs = obs_space.shape[0]
    if obs_dim != want_obs:
        raise _refuse(path, f"it takes a {obs_dim}-D observation but the env config's features "
                            f"({', '.join(env_config.obs_features)}, stack "
                            f"{env_config.obs_stack}) make {want_obs}-D" + _hint_obs(obs_dim))
    act_dim, fields = _box(path, data, "action_space")
    want_act = act_space.shape[0]
    if act_dim != want_act:
        fits = [a for a, n in ACTIONS.items() if n == act_dim]
        hint = f"; --env.action {' or '.join(fits)} has {act_dim}" if fits else ""
        raise _refuse(path, f"its action is {act_dim}-D but the env's action "
                            f"{env_config.action!r} is {want_act}-D{hint}")
    for side, want in (("low", -1.0), ("high", 1.0)):
        vals = _numbers(fields.get(side))
        if vals is None or len(vals) not in (1, act_dim) or any(v != want for v in vals):
            raise _refuse(path, f"its action bounds ({side} {fields.get(side)!r}) are not the "
                                "env's [-1, 1]")
    return obs_dim, act_dim


# --- the weights ------------------------------------------------------------------------------
def _widths(state: dict, prefix: str, path: Path) -> list[int]:
    """Hidden widths of an SB3 MLP (Linear at 0, 2, 4, ...) from its weight shapes."""
    mine = [k for k in state if k.startswith(prefix)]
    # An SB3 MLP's keys are PREFIX<index>.weight / .bias, each weight a 2-D matrix, each bias
    # 1-D: anything else (mlp_extractor.policy_net.abc.weight, a 1-D "weight") is no MLP here.
    odd = [k for k in mine if not re.fullmatch(r"\d{1,3}\.(weight|bias)", k[len(prefix):])
           or state[k].ndim != (2 if k.endswith(".weight") else 1)]
    if odd:
        raise _refuse(path, f"its {prefix[:-1]} holds {odd[0][:80]} of shape "
                            f"{tuple(state[odd[0]].shape)}, which is no layer of an SB3 MLP")
    keys = sorted((k for k in mine if k.endswith(".weight")),
                  key=lambda k: int(k[len(prefix):].split(".")[0]))
    indices = [int(k[len(prefix):].split(".")[0]) for k in keys]
    if indices != list(range(0, 2 * len(keys), 2)):
        raise _refuse(path, f"its {prefix[:-1]} layers ({', '.join(keys) or 'none'}) are not "
                            "an SB3 MLP's")
    return [int(state[k].shape[0]) for k in keys]


def _arch(stated, pi: list[int], vf: list[int], path: Path):
    inferred = pi if pi == vf else {"pi": pi, "vf": vf}
    if stated is None:
        return inferred
    as_dict = stated if isinstance(stated, dict) else {"pi": stated, "vf": stated}
    if as_dict != {"pi": pi, "vf": vf}:
        raise _refuse(path, f"its policy_kwargs say net_arch {stated!r} but its weights have "
                            f"pi {pi}, vf {vf}")
    return inferred


def read_weights(path: Path, data: dict, kwargs: dict, obs_dim: int, act_dim: int
                 ) -> tuple[dict, dict]:
    """-> (policy spec, state dict): the architecture inferred from the weights, checked against
    ``data``; the weights read as tensors only."""
    import torch

    state = _read_tensors(path, "policy.pth")
    if not isinstance(state, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
        raise _refuse(path, "its policy.pth holds no state dict of tensors")
    extra = sorted(k for k in state if "features_extractor" in k)
    if extra:
        raise _refuse(path, f"its features extractor has weights ({extra[0]}); only the flat "
                            "MLP input is rebuilt")
    for key in ("action_net.weight", "value_net.weight", "log_std",
                "mlp_extractor.policy_net.0.weight", "mlp_extractor.value_net.0.weight"):
        if key not in state:
            raise _refuse(path, f"its policy.pth has no {key}; not an MlpPolicy with a "
                                "Gaussian action")
    for key in ("action_net.weight", "value_net.weight"):
        if state[key].ndim != 2:
            raise _refuse(path, f"its {key} has shape {tuple(state[key].shape)}, not a matrix")
    if state["log_std"].ndim != 1:
        raise _refuse(path, f"its log_std has shape {tuple(state['log_std'].shape)}, not a "
                            "vector")
    pi = _widths(state, "mlp_extractor.policy_net.", path)
    vf = _widths(state, "mlp_extractor.value_net.", path)
    if state["mlp_extractor.policy_net.0.weight"].shape[1] != obs_dim or \
            state["action_net.weight"].shape[0] != act_dim or \
            tuple(state["log_std"].shape) != (act_dim,):
        raise _refuse(path, "its weights do not fit its own spaces "
                            f"({obs_dim}-D observation, {act_dim}-D action)")
    arch = _arch(kwargs.get("net_arch"), pi, vf, path)
    log_std = kwargs.get("log_std_init")
    if log_std is None:  # not stated: the trained log std, rather than SB3's default 0
        log_std = round(float(state["log_std"].float().mean()), 6)
    spec = {"net_arch": arch, "activation_fn": _activation(path, kwargs), "log_std_init": log_std}
    check_policy_spec(spec, f"{path}: cannot adopt")
    if not all(bool(torch.isfinite(v).all()) for v in state.values()):
        raise _refuse(path, "its weights hold NaN or infinite values")
    return spec, state


# --- RL Zoo's files beside the zip ------------------------------------------------------------
def _zoo_yaml(path: Path, file: Path) -> dict:
    """RL Zoo's config.yml / args.yml, read safely: its OrderedDict tag becomes a dict, tuples
    lists; any other Python tag is refused by yaml's SafeLoader."""
    import yaml

    class Loader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            # An alias repeats a node by reference: nine levels of ten make a 535-byte file
            # expand to 10^9 values (a "billion laughs"). RL Zoo writes none, so refuse any,
            # before anything is built or formatted into a message.
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise yaml.composer.ComposerError(
                    None, None, "uses a YAML alias (*name), which RL Zoo never writes", mark)
            return super().compose_node(parent, index)

    def ordered(loader, node):
        (pairs,) = loader.construct_sequence(node, deep=True)
        return dict(pairs)

    Loader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
                           ordered)
    Loader.add_constructor("tag:yaml.org,2002:python/tuple",
                           lambda loader, node: loader.construct_sequence(node, deep=True))
    if file.stat().st_size > MAX_ZOO_FILE_BYTES:
        raise _refuse(path, f"{file} is larger than {MAX_ZOO_FILE_BYTES:,} bytes; not RL Zoo's")
    try:
        out = yaml.load(file.read_text(), Loader=Loader)  # noqa: S506 (a SafeLoader)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise _refuse(path, f"cannot read RL Zoo's settings in {file} safely: {first[:160]}") \
            from None
    return out if isinstance(out, dict) else {}


def _short(value, limit: int = 120) -> str:
    """A value from a foreign file, as it goes into an error line: repr, cut to ``limit``."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def zoo_folder(path: Path) -> Path | None:
    """RL Zoo's params folder of the run the zip is in, if any: RL Zoo saves RUN/ENV.zip (and
    RUN/best_model.zip, RUN/rl_model_N_steps.zip) beside RUN/ENV/{config,args}.yml."""
    found = sorted(p.parent for p in path.parent.glob("*/config.yml")
                   if (p.parent / "args.yml").is_file())
    named = path.with_suffix("")
    if named in found:
        return named
    return found[0] if len(found) == 1 else None


def check_normalization(path: Path) -> Path | None:
    """Refuse a model trained on VecNormalize'd observations; -> RL Zoo's params folder."""
    run = path.parent
    pickles = sorted(p for pattern in ("*vecnormalize*.pkl", "*/vecnormalize.pkl")
                     for p in run.glob(pattern))
    folder = zoo_folder(path)
    normalize = _zoo_yaml(path, folder / "config.yml").get("normalize") if folder else None
    if pickles or normalize:
        what = pickles[0] if pickles else (f"normalize: {_short(normalize)} in "
                                           f"{folder / 'config.yml'}")
        raise _refuse(path, f"it was trained with VecNormalize ({what}): its observations were "
                            "normalised by running statistics that live only in a pickle, "
                            "which this repo never unpickles, and without them the weights see "
                            "other inputs; retrain with normalize: False (the env scales its "
                            "own observations, hyperparams/ppo.yml)")
    return folder


def check_zoo_env(path: Path, folder: Path, env_config: EnvConfig) -> None:
    """The env settings RL Zoo trained with (config.yml's env_kwargs, or args.yml's
    --env-kwargs when the config has none, as RL Zoo applies them) must be the env config's."""
    config = _zoo_yaml(path, folder / "config.yml")
    args = _zoo_yaml(path, folder / "args.yml")
    kwargs = (args.get("env_kwargs") if "env_kwargs" not in config else None) or \
        config.get("env_kwargs") or {}
    if not isinstance(kwargs, dict):
        raise _refuse(path, f"RL Zoo's env_kwargs in {folder} are not a mapping: "
                            f"{_short(kwargs)}")
    try:
        trained = EnvConfig().merged({k: v for k, v in kwargs.items() if k not in NOT_CONFIG})
    except UserError as exc:
        raise _refuse(path, f"RL Zoo's env_kwargs in {folder}: {exc}") from None
    a, b = trained.to_dict(), env_config.to_dict()
    diff = [k for k in a if a[k] != b[k]]
    if diff:
        k = diff[0]
        raise _refuse(path, f"RL Zoo trained it with {k} = {_short(a[k])} ({folder / 'config.yml'}) "
                            f"but the env config says {_short(b[k])}; add --env.{k.replace('_', '-')} "
                            "to match")


# --- the whole check --------------------------------------------------------------------------
def inspect(path: str | Path, env_config: EnvConfig) -> Foreign:
    """Everything adoption checks, reading nothing but JSON, YAML and tensors; ModelError (one
    line) on the first flaw."""
    path = Path(path)
    _check_zip_file(path)
    data = read_data(path)
    _policy_class(path, data)
    folder = check_normalization(path)
    kwargs = _policy_kwargs(path, data)
    obs_dim, act_dim = check_spaces(path, data, env_config)
    spec, state = read_weights(path, data, kwargs, obs_dim, act_dim)
    if folder is not None:
        check_zoo_env(path, folder, env_config)
    steps = data.get("num_timesteps", 0)
    if type(steps) is not int or steps < 0:
        raise _refuse(path, f"its num_timesteps is {steps!r}, not a count")
    try:
        version = read_member(path, "_stable_baselines3_version", 64).decode().strip()
    except (ModelError, UnicodeDecodeError):
        version = "?"
    hyper = {k: data[k] for k in HYPERPARAMS if isinstance(data.get(k), int | float)
             and not isinstance(data.get(k), bool) and math.isfinite(data[k])}
    return Foreign(path, spec, state, steps, version, hyper,
                   str(folder) if folder is not None else None)


def own_model(path: Path, overrides: dict) -> tuple[Foreign, EnvConfig, dict]:
    """A model of this repo, loaded as every model is (models.load_policy: the bound sidecar's
    architecture, weights only), its sidecar's env plus ``overrides``, which must keep the
    model's spaces, and the sidecar's env as it was."""
    from .models import load_policy

    policy, env, side = load_policy(path)
    env_config = EnvConfig.from_dict(env).merged(overrides)
    want = tuple(s.shape for s in spaces_for(env_config))
    have = (policy.observation_space.shape, policy.action_space.shape)
    if want != have:
        raise _refuse(path, f"the settings given make a {want[0][0]}-D observation and a "
                            f"{want[1][0]}-D action; the model has {have[0][0]} and {have[1][0]}")
    train = side.get("train_config") if isinstance(side.get("train_config"), dict) else {}
    hyper = {k: train[k] for k in HYPERPARAMS if isinstance(train.get(k), int | float)
             and not isinstance(train.get(k), bool)}
    return Foreign(path, side["policy"], policy.state_dict(), side.get("timesteps", 0),
                   side.get("sb3_version", "?"), hyper), env_config, env


def _sb3_model(foreign: Foreign, env_config: EnvConfig):
    """A fresh PPO built here from the spec (on a stand-in env with the right spaces), holding
    the adopted weights: what the archive stores, in SB3's format, made by this code."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO

    from .models import policy_kwargs_of

    obs_space, act_space = spaces_for(env_config)

    class Spaces(gym.Env):  # never stepped: PPO only reads its spaces
        observation_space, action_space = obs_space, act_space

    kwargs = policy_kwargs_of({"policy": foreign.spec})
    model = PPO("MlpPolicy", Spaces(), device="cpu", use_sde=kwargs.pop("use_sde", False),
                policy_kwargs=kwargs)
    with torch.no_grad():
        model.policy.load_state_dict(foreign.state)
    model.num_timesteps = foreign.timesteps
    return model


def adopt(src: str | Path, name: str, overrides: dict | None = None, force: bool = False,
          log=print) -> Path:
    """Check ``src`` against the env config (defaults plus ``overrides``, as ``--env.*``), run
    the quick test and write archive/NAME.zip, NAME.json and NAME.md; -> the zip's path."""
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy

    from .controllers import make_policy
    from .models import load_policy, policy_kwargs_of, save_model, sidecar_path
    from .seeds import QUICK_TEST_SEEDS
    from .training.archive import archive_path, card_number, check_archive_free, write_card
    from .training.evaluation import evaluate

    check_plain_name(name, "--name")
    src = Path(src)
    # fail before the work; checked again under the lock
    check_archive_free(name, force, flag="--name")
    changed = None
    if sidecar_path(src).is_file():  # this repo's own model: its env, then the flags given
        foreign, env_config, before = own_model(src, overrides or {})
        changed = {k: v for k, v in env_config.to_dict().items() if before.get(k) != v}
    else:
        env_config = EnvConfig().merged(overrides or {})
        foreign = inspect(src, env_config)
    obs_space, act_space = spaces_for(env_config)
    policy = ActorCriticPolicy(obs_space, act_space, lambda _: 0.0,
                               **policy_kwargs_of({"policy": foreign.spec}))
    try:
        policy.load_state_dict(foreign.state)
    except RuntimeError as exc:
        raise _refuse(src, f"its weights do not fit the inferred MlpPolicy "
                           f"({str(exc).splitlines()[0][:160]})") from None
    policy.set_training_mode(False)
    log(f"checked {src}: MlpPolicy {foreign.spec['net_arch']} {foreign.spec['activation_fn']}, "
        f"{obs_space.shape[0]}-D observation, {act_space.shape[0]}-D action, "
        f"{foreign.timesteps:,} steps; running the quick test "
        f"(seeds {QUICK_TEST_SEEDS[0]}-{QUICK_TEST_SEEDS[-1]}, 5 s)")
    env_dict = env_config.to_dict()
    test = evaluate(make_policy(policy), env_dict, 500,
                    episodes=[(s, None) for s in QUICK_TEST_SEEDS])
    seed0 = card_number(policy, env_dict)
    adopted = {"sha256": file_sha256(src), "sb3_version": foreign.sb3_version,
               "algo": "PPO", "hyperparams": foreign.hyperparams,
               **({"rl_zoo_run": foreign.zoo_run} if foreign.zoo_run else {}),
               **({"env_changed": changed} if changed is not None else {})}
    sidecar = {"env_config": env_dict, "timesteps": foreign.timesteps, "test_metrics": test,
               "test_seed0_mean_error_cm": seed0, "name": name, "source": str(src),
               "adopted": adopted}
    dst = archive_path(name)
    dst.parent.mkdir(parents=True, exist_ok=True)
    model = _sb3_model(foreign, env_config)
    with archive_lock(dst):
        check_archive_free(name, force, flag="--name")
        save_model(model, dst, sidecar)
        stored, _, side = load_policy(dst)  # the pair as written loads, weights only
        same = stored.state_dict()
        if set(same) != set(foreign.state) or not all(
                torch.equal(same[k], foreign.state[k].to(same[k].dtype)) for k in same):
            raise RuntimeError(f"{dst}: the archived weights differ from the adopted ones")
        write_card(dst, side)
    log(f"adopted {src} as {dst} (+ {sidecar_path(dst).name}, {dst.with_suffix('.md').name}): "
        f"quick test mean error {test['mean_error_cm']:.2f} cm, test seed 0 {seed0:.6f} cm")
    return dst
