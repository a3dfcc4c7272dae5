"""The learning check: on an easy setting (circles only), a small PPO budget must already
track clearly better than the classical controller on the evaluation circles."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_policy_beats_classical_on_circles_within_a_small_budget(tmp_path):
    import json

    from panda_lead.controllers import classical, make_policy
    from panda_lead.models import load_policy
    from panda_lead.seeds import EVAL_SET
    from panda_lead.training import evaluate

    cmd = [sys.executable, str(ROOT / "train.py"), "--preset", "v1", "--timesteps", "150000",
           "--n-envs", "16", "--vec-env", "dummy", "--n-steps", "256", "--batch-size", "1024",
           "--log-std-init", "-1", "--eval-freq", "50000", "--runs-dir", str(tmp_path),
           "--no-progress", "--seed", "3"]
    subprocess.run(cmd, cwd=tmp_path, check=True, capture_output=True, timeout=900)
    run = next(tmp_path.iterdir())
    model, env_config, _ = load_policy(run / "best_model.zip")
    circles = [(s, shape) for s, shape in EVAL_SET if shape == "circle"]
    policy = evaluate(make_policy(model), env_config, 500, circles)["mean_error_cm"]
    base = evaluate(classical, env_config, 500, circles)["mean_error_cm"]
    print(json.dumps({"policy_cm": policy, "classical_cm": base}))
    assert policy < base - 1.0, (policy, base)
