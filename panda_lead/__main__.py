"""``python -m panda_lead COMMAND [flags]``: the ``panda-lead`` console command (cli/main.py)."""

import sys

from .cli.main import main

sys.exit(main(prog="python -m panda_lead"))
