"""Training: the config (`TrainConfig`) and presets, the training envs and their seeding, the
evaluation runs are selected on, the callbacks, the loop (`train`) and the archive."""

from .archive import archive_model, write_card  # noqa: F401
from .callbacks import SpeedCurriculum, speed_cap  # noqa: F401
from .config import REFERENCE_HPARAMS, TrainArgs, TrainConfig  # noqa: F401
from .envs import make_vec_env  # noqa: F401
from .evaluation import evaluate  # noqa: F401
from .loop import TrainingInterrupted, train  # noqa: F401
from .presets import PRESETS, get_preset, preset_table  # noqa: F401
