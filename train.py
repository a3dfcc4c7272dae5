"""Train a PPO lead policy: `uv run train.py [--preset v5] [--timesteps N] [--archive NAME]`.

A face of the package: the command line is panda_lead.cli.train, the loop
panda_lead.training.loop. `uv run train.py --help` lists every flag and preset.
"""

if __name__ == "__main__":
    from panda_lead.cli.train import main

    main()
