"""The model archive: a run's best model becomes ``archive/NAME.zip`` with its sidecar
(``NAME.json``, which the zip also carries) and a model card (``NAME.md``) whose snippet
reproduces a number of the card exactly, from any folder.

A card is written by ``write_card``; ``rewrite_cards`` rewrites every card of archive/ from
its zip (the zips and their sidecars untouched), e.g. after the card's template changes:

    uv run python -c "from panda_lead.training.archive import rewrite_cards; rewrite_cards()"
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from ..controllers import make_policy
from ..errors import UserError, check_plain_name
from ..models import (
    ARCHIVE_DIR,
    archive_lock,
    copy_with_sidecar,
    file_sha256,
    load_policy,
    pair_state,
)
from ..roles import role
from ..seeds import QUICK_TEST_SEEDS
from ..trajectory import SHAPES
from .evaluation import evaluate


def archive_path(name: str) -> Path:
    return ARCHIVE_DIR / f"{check_plain_name(name, '--archive')}.zip"


def check_archive_free(name: str, force: bool, flag: str = "--archive") -> None:
    """UserError unless archive/NAME is free (or ``force``); says what is there, and names
    ``flag``, the option that chose the name (train.py's --archive, eval.py --adopt's --name)."""
    path = archive_path(name)
    state = pair_state(path)
    if force:
        return
    card = path.with_suffix(".md")
    if state == "absent":
        # The card is written too: a NAME.md alone (notes, a card whose pair was moved) is
        # someone's file, never replaced without --force.
        if card.exists() or card.is_symlink():
            raise UserError(f"{card} exists (a card without its model); choose another name, "
                            "or add --force to replace it")
        return
    if state == "valid":
        raise UserError(f"{path} exists; choose another {flag} name, or add --force to "
                        "replace it")
    raise UserError(f"{path} exists but {state}; restore its sidecar from the model with "
                    f"`uv run eval.py --model {path} --restore-sidecar`, or add --force to "
                    "replace it")


def archive_model(run_dir: Path, name: str, force: bool = False, caveats: tuple[str, ...] = ()
                  ) -> Path:
    """Archive the run's best (else final) model as archive/NAME.zip: the same weights and
    sidecar, plus quick-test metrics, the card's number and ``caveats``; then the card.
    Holds the name's lock while it checks and writes, so of two runs archiving one name, the
    second is refused with one line instead of replacing the first."""
    src = Path(run_dir) / "best_model.zip"
    if not src.is_file():
        src = Path(run_dir) / "final_model.zip"
    policy, env_config, side = load_policy(src)
    test = evaluate(make_policy(policy), env_config, 500,
                    episodes=[(s, None) for s in QUICK_TEST_SEEDS])
    seed0 = pinned_card_number(src, policy, env_config)
    dst = archive_path(name)
    with archive_lock(dst):
        check_archive_free(name, force)
        extra = {"test_metrics": test, "test_seed0_mean_error_cm": seed0, "name": name,
                 "source": str(src), **({"caveats": list(caveats)} if caveats else {})}
        side = copy_with_sidecar(src, dst, extra)
        write_card(dst, side, seed0)
    return dst


def card_number(policy, env_config: dict) -> float:
    """Mean tracking error (cm) on test seed 0, 5 s: the number the model card promises, played
    exactly as the card's snippet plays it (the single env by id, SB3's float32
    ``policy.predict``). Not eval.py's way (the float64 numpy actor of ``make_policy`` through
    the batched task): the two actions differ by ~1e-7, which a lead policy keeps within the
    6 printed digits and a jerky one (ikfree: 5.408674 cm vs 5.588987) does not."""
    import gymnasium as gym
    import numpy as np

    e = gym.make("PandaLead-v0", **{**env_config, "episode_steps": 500})
    try:
        obs, _ = e.reset(seed=0, options={"traj_seed": 0})
        errors, done = [], False
        while not done:
            action, _ = policy.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = e.step(action)
            errors.append(info["distance"])
            done = terminated or truncated
    finally:
        e.close()
    return float(100 * np.mean(errors))


# torch's MKL picks its matrix kernels by CPU (AVX-512, AVX2 or SSE, by model and vendor), and
# float32 sums come out in another order: a lead policy's seed-0 number moves in its sixth
# digit, a chaotic closed loop's (the IK-free policies) by millimetres. A card promises the
# number on one path that every x86 CPU has, SSE4.2, read by MKL when torch first calls it.
PINNED_MATRIX_PATH = {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2"}


def pinned_card_number(zip_path: Path, policy=None, env_config: dict | None = None) -> float:
    """card_number() of the zip with torch's matrix kernels on PINNED_MATRIX_PATH: in this
    process when it already runs on it (``policy`` and ``env_config`` reused if given), else
    in a fresh interpreter that does (a few seconds), so that the card's snippet prints the
    same number on any x86 CPU run with the same setting."""
    if all(os.environ.get(k) == v for k, v in PINNED_MATRIX_PATH.items()):
        if policy is None:
            policy, env_config, _ = load_policy(zip_path)
        return card_number(policy, env_config)
    code = ("import sys; from panda_lead.models import load_policy; "
            "from panda_lead.training.archive import card_number; "
            "policy, env_config, _ = load_policy(sys.argv[1]); "
            "print(repr(card_number(policy, env_config)))")
    out = subprocess.run([sys.executable, "-c", code, str(Path(zip_path).resolve())],
                         env={**os.environ, **PINNED_MATRIX_PATH}, capture_output=True,
                         text=True)
    if out.returncode != 0:  # a bug in the code above, not bad input: keep its traceback
        raise RuntimeError(f"the card's number for {zip_path} failed in a child process:\n"
                           f"{out.stderr[-2000:]}")
    return float(out.stdout.strip().splitlines()[-1])


def _changed_from_preset(train: dict) -> str:
    """' with learning_rate 0.0003 (the preset: 0.001)': what the run's flags changed from its
    preset, so a card does not pass a flag-trained model off as the preset's. Budget, seed
    and evaluation settings are the run's own and not listed."""
    from .config import TrainConfig
    from .presets import PRESETS

    base = PRESETS.get(train.get("preset"))
    if base is None:
        return ""
    try:  # through the config class, so an older layout of the same values compares equal
        ran = TrainConfig.from_dict(train).to_dict()
    except (TypeError, ValueError, UserError):
        return ""
    named, own = base.to_dict(), ("seed", "preset", "timesteps", "eval_freq", "checkpoint_freq")
    env = [f"{k} {v} (the preset: {named['env'].get(k)})" for k, v in sorted(ran["env"].items())
           if named["env"].get(k) != v]
    rest = [f"{k} {v} (the preset: {named.get(k)})" for k, v in sorted(ran.items())
            if k not in (*own, "env") and named.get(k) != v]
    changed = rest + [f"env.{c}" for c in env]
    return f" with {', '.join(changed)}" if changed else ""


CARD_SNIPPET = '''\
import gymnasium as gym
import numpy as np

import panda_lead  # noqa: F401  (registers PandaLead-v0)
from panda_lead.models import archived, load_policy

# Weights only, never unpickled; found in ./archive or the archive shipped with the package.
policy, env_config, sidecar = load_policy(archived("{name}"))
e = gym.make("PandaLead-v0", **{{**env_config, "episode_steps": 500}})
obs, _ = e.reset(seed=0, options={{"traj_seed": 0}})
errors, done = [], False
while not done:
    action, _ = policy.predict(obs, deterministic=True)
    obs, reward, terminated, truncated, info = e.step(action)
    errors.append(info["distance"])
    done = terminated or truncated
print(f"test seed 0: mean error {{100 * np.mean(errors):.6f}} cm")  # card: {seed0:.6f} cm
'''


def write_card(zip_path: Path, side: dict, seed0: float | None = None) -> Path:
    """archive/NAME.md: what the model is, its config, its test results, how to load it. The
    card promises ``seed0``, by default the zip played as its snippet plays it, on the pinned
    matrix path (so the promise is what the snippet prints, whatever way an older sidecar's
    number was computed)."""
    from ..atomicio import atomic_write

    zip_path = Path(zip_path)
    if seed0 is None:
        seed0 = pinned_card_number(zip_path)
    stored = side.get("test_seed0_mean_error_cm")
    older = "" if stored is None or f"{stored:.6f}" == f"{seed0:.6f}" else (
        f"\nThe sidecar's `test_seed0_mean_error_cm` ({stored:.6f} cm) was computed eval.py's way "
        "(the float64\nnumpy actor through the batched task, with the matrix kernels of the CPU "
        "that trained it); the\nsnippet's float32 `predict` differs from it by ~1e-7 in the "
        "action, which this policy amplifies" + (
            ",\nand the snippet plays the model's own training env, whose observation noise "
            "changed\nafter it was archived (2026-11-26: the tip error carries the position "
            "readings' noise)." if train_noise_changed(side) else "."))
    name = zip_path.stem
    train = side.get("train_config", {})
    test = side.get("test_metrics", {})
    env_rows = "\n".join(f"| {k} | {v} |" for k, v in sorted(side["env_config"].items()))
    train_rows = "\n".join(f"| {k} | {v} |" for k, v in sorted(train.items()) if k != "env")
    shape_rows = "\n".join(
        f"| {s} | {test[f'{s}/mean_error_cm']:.2f} | {test[f'{s}/in_band_pct']:.1f} |"
        for s in SHAPES if f"{s}/mean_error_cm" in test)
    preset = train.get("preset")
    from_preset = f" from preset `{preset}`{_changed_from_preset(train)}" if preset else ""
    steps, budget = side.get("timesteps", 0), train.get("timesteps")
    # A run's best model can come from any evaluation of it: its own step count is not the
    # run's budget (ikfree_long's best came at 5.0M of 30M steps).
    when = (f"Selected at step {steps:,} of a {budget:,}-step run (its lowest evaluation-set "
            f"error){from_preset}, seed {train.get('seed', '?')}, after {side.get('wall_time_s', '?')} s"
            if budget and steps and budget - steps > train.get("eval_freq", 0) else
            f"Trained {steps:,} steps{from_preset}, seed {train.get('seed', '?')}, "
            f"{side.get('wall_time_s', '?')} s")
    start = side.get("init_from") or {}
    # A warm-started model's steps are on top of its starting model's (training/warm_start.py).
    started = (f" Started from `{start.get('path', '?')}` (sha256 "
               f"`{str(start.get('sha256', '?'))[:12]}`), not from random weights: its steps "
               "are on top of that model's." if start else "")
    adopted = side.get("adopted") or {}
    changed = adopted.get("env_changed")
    source = (f"this repo's model, sha256 `{str(adopted.get('sha256', '?'))[:12]}`, its weights "
              f"unchanged; run with {', '.join(f'{k} = {v!r}' for k, v in changed.items())}"
              if changed is not None else "trained outside this repo's train.py")
    origin = (f"{when}, code commit `{side.get('commit', '?')}`.{started}" if train else
              f"Adopted from `{side.get('source', '?')}` ({source}).")
    caveats = "".join(f"\n**Caveat.** {c}\n" for c in side.get("caveats", []))
    what_for = role(zip_path.stem)  # (a long path stays whole on its line)
    what_for = what_for and textwrap.fill(what_for, 95, break_long_words=False,
                                          break_on_hyphens=False)
    role_section = f"\n## Role\n\n{what_for}\n" if what_for else ""
    action = side["env_config"].get("action", "lead")
    what = {"lead": "a Cartesian lead added to the IK target of a classical IK+PD",
            "joint": "a joint-goal residual added to the IK's joint goal in a classical IK+PD",
            "joint_target": "the joint position goals directly (no IK in the loop) to the joint "
                            "PD of a"}[action]
    seeds = f"{QUICK_TEST_SEEDS[0]}-{QUICK_TEST_SEEDS[-1]}"
    policy = side.get("policy", {})
    text = f"""# Model card: {name}

A PPO policy (stable-baselines3, MLP {policy.get('net_arch', '?')}, {policy.get('activation_fn', '?')})
that outputs {what} Franka Panda controller (`PandaLead-v0`).
{origin}
Files: `{name}.zip` (SB3 format, carrying its sidecar), `{name}.json` (the same sidecar and
`model_sha256`, the zip's SHA-256), this card.
{role_section}{caveats}
## Test results (quick test seeds {seeds}, 5 s episodes, shape drawn from the seed)

| set | mean error (cm) | time in 5 cm band (%) |
|---|---|---|
| all | {test.get('mean_error_cm', float('nan')):.2f} | {test.get('in_band_pct', float('nan')):.1f} |
{shape_rows}{training_world(side["env_config"])}

Test seed 0 alone: {seed0:.6f} cm (the snippet below reproduces it on any x86 CPU with torch's
matrix kernels pinned, `MKL_ENABLE_INSTRUCTIONS=SSE4_2`; other kernels can move its last
digits, a chaotic closed loop's by millimetres).{older}
Where this model has full results (1,000 test seeds, paired with the baselines): README,
docs/results.md or docs/questions.md.

## Load it

From any folder, once the project is installed (`uv sync`, or `pip install .`). `PPO.load`
would unpickle objects stored in the zip (running any code a tampered file carries);
`load_policy` rebuilds the policy from the sidecar the zip carries and reads only tensors
(`torch.load(weights_only=True)`), after checking the zip's SHA-256.

```python
{CARD_SNIPPET.format(name=name, seed0=seed0)}```

## Env config

| setting | value |
|---|---|
{env_rows}

## Training config

| setting | value |
|---|---|
{train_rows or '| (adopted: see the source) | |'}

SHA-256 of the zip: `{side.get('model_sha256') or file_sha256(zip_path)}`
"""
    out = zip_path.with_suffix(".md")
    with atomic_write(out, ".tmp.md") as tmp:
        Path(tmp).write_text(text)
    return out


def train_noise_changed(side: dict) -> bool:
    """Whether the card's snippet, which plays the model's own training env, may meet a noise
    model other than the one it trained under: noise on a position with the tip error observed,
    which since 2026-11-26 carries the position readings' noise (not an independent draw)."""
    env = side.get("train_config", {}).get("env", {})
    noise, features = env.get("obs_noise") or {}, env.get("obs_features") or ()
    return bool({"tip_error", "tip_error_avg"} & set(features)) and bool(
        noise.get("ee_pos") or noise.get("target_pos"))


def training_world(env: dict) -> str:
    """The card's words for a model whose quick test plays its own training world when that
    world is not the nominal one (latency or noise drawn per episode): its figures are then not
    the nominal test's, and a reader comparing them with the README's would be misled."""
    delays = [env.get(k) or 0 for k in ("obs_delay", "action_delay", "target_delay")]
    noisy = bool(env.get("obs_noise"))
    if not (any(delays) or noisy):
        return ""
    parts = []
    if any(delays):
        parts.append(f"latency {'0-' if env.get('random_delay') else ''}{max(delays)} steps")
    if noisy:
        level = env["obs_noise"].get("target_pos") or env["obs_noise"].get("ee_pos") or 0
        parts.append(f"observation noise {'0-' if env.get('random_noise') else ''}"
                     f"{100 * level:g} cm")
    share = env.get("nominal_share")
    nominal = f", {share:.0%} of episodes nominal" if share else ""
    return (f"\n\nPlayed in the model's own training world ({', '.join(parts)}{nominal}), not the "
            "nominal one: its nominal and per-condition rows are in `uv run studies/deploy.py`'s "
            "tables (docs/deploy.md).")


def rewrite_cards(names=None) -> list[Path]:
    """Rewrite archive/NAME.md for each name (default: every archive/*.zip) from its zip and the
    sidecar it carries; the zips and their JSONs are not touched."""
    from ..models import verify

    zips = ([archive_path(n) for n in names] if names is not None
            else sorted(ARCHIVE_DIR.glob("*.zip")))
    return [write_card(z, verify(z)) for z in zips]
