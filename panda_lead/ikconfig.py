"""The classical controller's IK settings (`IKConfig`) and the arm's joint count: plain data,
no MuJoCo, so that the env's configuration (config.py) sits below the simulation. core.py
re-exports both."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .errors import UserError, check_typed_fields, did_you_mean

N_JOINTS = 7  # the Panda's arm joints (the fingers are not actuated in this scene)


@dataclass(frozen=True)
class IKConfig:
    """The classical controller's IK, every knob of it (EnvConfig.ik; ``--env.ik.damping``)."""

    damping: float = field(default=0.05, metadata={"range": (0.0, 10.0)})
    """DLS damping lambda (m): keeps steps finite near singularities and out-of-reach targets."""
    iters: int = field(default=1, metadata={"range": (1, 100)})
    """DLS iterations per IK solve, each from the last (the first from the measured angles)."""
    nullspace_gain: float = field(default=0.1, metadata={"range": (0.0, 1.0)})
    """Pull towards the home posture in the Jacobian's null space, so the elbow does not drift."""
    max_step: float = field(default=0.5, metadata={"range": (1e-6, 10.0)})
    """Largest joint change per iteration (rad, infinity norm)."""
    limit_margin: float = field(default=0.02, metadata={"range": (0.0, 0.5)})
    """Joint goals stay this far (rad) inside the joint limits."""
    clearance: float = field(default=0.0, metadata={"range": (0.0, 0.2)})
    """Collision-aware IK: keep the arm's collision capsules this far apart (m; e.g. 0.02) by a
    velocity damper on the IK step (clearance.py); 0: off, the plain IK. Needs iters 1."""
    substep_ik: bool = False
    """Solve the IK before every physics substep (500 Hz) on the target at that instant, the
    lead held over the control step, instead of once per control step (100 Hz): the reference
    work's rate, for an apples-to-apples baseline. Five times the IK work per step."""

    def __post_init__(self):
        check_typed_fields(self, "ik.")
        if self.clearance > 0 and self.iters != 1:
            raise UserError(f"ik.clearance needs ik.iters 1, got clearance {self.clearance} "
                            f"with iters {self.iters}")

    @classmethod
    def from_dict(cls, settings) -> IKConfig:
        if isinstance(settings, IKConfig):
            return settings
        if not isinstance(settings, dict):
            raise UserError(f"ik must be a mapping of IK settings, got {settings!r}")
        names = [f.name for f in dataclasses.fields(cls)]
        for k in settings:
            if k not in names:
                raise UserError(f"unknown IK setting {k!r}" + did_you_mean(k, names))
        return cls(**settings)


DEFAULT_IK = IKConfig()  # (a frozen value: safe as a default argument)
