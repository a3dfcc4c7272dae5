"""Start a run from a trained model's weights (`TrainConfig.init_from`).

A run that observes more than its starting model (the planned path, the previous action, the
installation, older observations stacked behind the newest) gets the model's weights for every
input the model had and zero weights for the new ones, so its first policy and value are the
model's, exactly; what the new inputs are worth is then what training finds, measured against
a control that continues the same model without them. Every other tensor must match in shape:
same network, same action.

The exploration starts afresh at the run's --log-std-init unless --init-keep-std keeps the
model's own; by default only the mean and the value are the model's. A trained lead's std is
0.04-0.10 (log_std -3.2 to -2.3), and PPO's clipped ratio lets such a narrow policy move its
mean only by a fraction of that per update: kept, the first try (deploy_large_batch from the
headline's seeds 1 and 3, a new world) sat at its starting evaluation error, 3.65-4.13 cm, for
1.1M steps, where the same preset from random weights went from 6.2 to 3.2 cm. In the model's
own world the wide restart costs instead: the 4-stack's seeds restarted at std 0.37 and lr 1e-3
(10M to 15M steps) averaged 2.75-2.82 cm over their first 1M steps, where their starts' best
were 2.28-2.43; the 15M seeds restarted near their own std (0.09) at lr 3e-4 averaged 2.22-2.36
(docs/deploy.md, "Trained on gently").
"""

from __future__ import annotations

from pathlib import Path

from ..config import obs_layout
from ..errors import UserError
from ..models import file_sha256, load_policy, verify

# The first layer of each MLP: the only tensors whose shape follows the observation.
FIRST_LAYERS = ("mlp_extractor.policy_net.0.weight", "mlp_extractor.value_net.0.weight")


def init_path(template: str, seed: int) -> Path:
    """The starting model of training seed ``seed``: ``{seed}`` in the template names one per
    seed (archive/seeds/v5_err_decay_kept_s{seed}.zip), so that a study's spread includes its
    starting models'."""
    return Path(template.replace("{seed}", str(seed)))


def check_init_from(template: str, seed: int, config) -> tuple[Path, dict]:
    """(path, sidecar) of a usable starting model, or one UserError line naming what does not
    fit: the model's network, action and observation stacking must be the run's, and every
    feature it observed must be among the run's."""
    path = init_path(template, seed)
    if not path.is_file():
        raise UserError(f"--init-from {path}: no such model")
    side = verify(path)  # a damaged or unbound model is one line
    train, env = side.get("train_config") or {}, side.get("env_config") or {}
    mine = config.env
    for what, theirs, ours in (("net_arch", list(train.get("net_arch", [])), list(config.net_arch)),
                               ("action", env.get("action", "lead"), mine.action)):
        if theirs != ours:
            raise UserError(f"--init-from {path}: its {what} is {theirs!r}, this run's {ours!r}")
    if env.get("obs_stack", 1) > mine.obs_stack:
        raise UserError(f"--init-from {path}: it stacks {env.get('obs_stack', 1)} observations, "
                        f"this run {mine.obs_stack}; a run may remember more than its starting "
                        "model, not less")
    missing = [f for f in env.get("obs_features", ()) if f not in mine.obs_features]
    if missing:
        raise UserError(f"--init-from {path}: it observes {', '.join(missing)}, which this run "
                        "does not; a run may observe more than its starting model, not less")
    return path, side


def _column_map(old_features, new_features, old_stack: int = 1) -> list[tuple[int, int, int]]:
    """(old start, new start, width) of each feature the old observation had, in each of its
    ``old_stack`` stacked observations (newest first: the new run's first ones; its older
    ones, if it stacks more, are new inputs)."""
    old_layout, new_layout = obs_layout(old_features), obs_layout(new_features)
    new = {f: start for f, start, _ in new_layout}
    old_base, new_base = old_layout[-1][2], new_layout[-1][2]
    return [(k * old_base + start, k * new_base + new[f], stop - start)
            for k in range(old_stack) for f, start, stop in old_layout]


def warm_start(model, template: str, config) -> dict:
    """Load the starting model's tensors into a freshly built PPO ``model`` (optimizer state
    fresh: Adam's moments belong to the old run's steps; log_std the run's own unless
    config.init_keep_std). Returns the
    record the run's sidecars keep: path and sha256 of the model it started from."""
    import torch

    path, side = check_init_from(template, config.seed, config)
    # models.load_policy: the weights checked finite and against the sidecar, never unpickled
    state = load_policy(path, str(model.device))[0].state_dict()
    target = model.policy.state_dict()
    if set(state) != set(target):
        raise UserError(f"--init-from {path}: its tensors ({len(state)}) are not this run's "
                        f"policy's ({len(target)}): another architecture")
    cols = _column_map(side["env_config"]["obs_features"], config.env.obs_features,
                       side["env_config"].get("obs_stack", 1))
    with torch.no_grad():
        for name, value in state.items():
            if name in FIRST_LAYERS:
                grown = torch.zeros_like(target[name])
                for old, new, width in cols:
                    grown[:, new:new + width] = value[:, old:old + width]
                value = grown
            if name == "log_std" and not config.init_keep_std:
                value = torch.full_like(target[name], config.log_std_init)
            if value.shape != target[name].shape:
                raise UserError(f"--init-from {path}: {name} is {tuple(value.shape)} there, "
                                f"{tuple(target[name].shape)} in this run")
            target[name] = value
    model.policy.load_state_dict(target)
    return {"path": str(path), "sha256": file_sha256(path)}
