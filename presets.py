"""The presets moved into training.py (`training.PRESETS`: name -> TrainConfig); this module
re-exports them for older imports."""

from models import OBS_12, OBS_15, OBS_29  # noqa: F401
from training import PRESET_DOCS, PRESETS, get_preset  # noqa: F401
