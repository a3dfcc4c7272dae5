"""Run a policy (or a baseline) on seeds: watch it, record a video, or write rollout files.

    uv run eval.py --seed 7 --model archive/v5.zip              # viewer (needs a display)
    uv run eval.py --seed 7 --video videos/v5_7.mp4             # offscreen MP4, any machine
    uv run eval.py --seed 7 --video videos/cmp.mp4 --compare    # classical | policy
    uv run eval.py --seeds 0-99 --prefix eval_v5 --model archive/v5.zip
    uv run eval.py --seeds 0-99 --prefix analytic --controller analytic

The env is rebuilt from the model's sidecar, so any archived model runs on any seed set.
"""

import os
import sys

from panda_lead.cli.run import run_controller_cli

if __name__ == "__main__":
    run_controller_cli(default_controller="policy", default_prefix="eval", argv=sys.argv[1:],
                       prog=os.path.basename(__file__), description=__doc__)
