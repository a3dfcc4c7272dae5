"""The command lines behind the root scripts (train.py, eval.py, ikpd.py, metrics.py,
trajectory.py): each root script is a few lines that call one of these."""
