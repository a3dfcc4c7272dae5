"""Train a PPO lead policy: `uv run train.py [--preset v5] [--timesteps N] [--archive NAME]`.

One folder per run under runs/: config.json (resolved), command.txt, tb/ (TensorBoard),
checkpoints/, best_model.zip (lowest evaluation-set tracking error) and final_model.zip, each
model with its sidecar. Ctrl-C saves the model and prints how to resume. The loop itself is
training.py; nothing imports this script.
"""

import sys

import tyro

from training import Args, train

if __name__ == "__main__":
    args = tyro.cli(Args, description=__doc__)
    try:
        train(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
