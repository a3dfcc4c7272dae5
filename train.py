"""Train a PPO lead policy: `uv run train.py [--preset v5] [--timesteps N] [--archive NAME]`.

One folder per run under runs/: config.json (the resolved config), command.txt, tb/
(TensorBoard), checkpoints/, best_model.zip (lowest evaluation-set tracking error) and
final_model.zip, each model with its sidecar. Ctrl-C or SIGTERM saves the model and prints how
to resume (`--resume RUN_FOLDER`). `--preset NAME` starts from a preset; every flag given
overrides it, and `--preset NAME --help` shows the preset's values. The loop itself is
training.py; nothing imports this script.
"""

import sys

from panda_lead.errors import exit_on_user_error
from panda_lead.training import parse_args, preset_table, train


@exit_on_user_error
def main(argv: list[str]) -> None:
    description = f"{__doc__}\nPresets:\n{preset_table()}"
    train(parse_args(argv, prog="train.py", description=description))


if __name__ == "__main__":
    main(sys.argv[1:])
