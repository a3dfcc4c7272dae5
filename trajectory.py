"""Analytic target trajectories: `uv run trajectory.py --seed 3 [--out traj.png]`.

A face of the package: the trajectories are panda_lead.trajectory (``import trajectory`` still
gives ``sample``, ``Trajectory`` and ``SHAPES``), the command line panda_lead.cli.trajectory.
"""

import sys

from panda_lead.trajectory import SHAPES, Trajectory, sample  # noqa: F401  (the contract)

if __name__ == "__main__":
    from panda_lead.cli.trajectory import main

    sys.exit(main(sys.argv[1:]))
