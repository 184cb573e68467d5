"""wmr_jax: a differentiable, batched simulator of the Shim–Sung (2003) pose controller."""

from wmr_jax import baselines as _baselines  # noqa: F401  (registers the baselines)
from wmr_jax.baselines import AicardiGains, AstolfiGains
from wmr_jax.controllers import SHIM_SUNG, Controller, get_controller, register_controller
from wmr_jax.law import (
    Diagnostics,
    PolarError,
    control,
    control_diagnostics,
    lyapunov,
    polar_error,
    region_label,
    wheel_speeds,
)
from wmr_jax.metrics import (
    arrival_time,
    arrived,
    path_length,
    region_time,
    success_rate,
    zigzag_count,
)
from wmr_jax.params import (
    Gains,
    Robot,
    WheelSpeedWarning,
    check_feasible,
    wheel_speed_bound,
)
from wmr_jax.reference import reference_control, reference_diagnostics, reference_rollout
from wmr_jax.sharding import ShardedBatch, shard, unpad
from wmr_jax.simulation import Options, Trajectory, batch_rollout, final_poses, rollout

__version__ = "0.1.0"

__all__ = [
    "AicardiGains",
    "AstolfiGains",
    "ShardedBatch",
    "shard",
    "unpad",
    "SHIM_SUNG",
    "Controller",
    "Options",
    "get_controller",
    "register_controller",
    "Diagnostics",
    "Gains",
    "PolarError",
    "Robot",
    "Trajectory",
    "WheelSpeedWarning",
    "arrival_time",
    "arrived",
    "batch_rollout",
    "check_feasible",
    "control",
    "control_diagnostics",
    "final_poses",
    "lyapunov",
    "path_length",
    "polar_error",
    "reference_control",
    "reference_diagnostics",
    "reference_rollout",
    "region_label",
    "region_time",
    "rollout",
    "success_rate",
    "wheel_speed_bound",
    "wheel_speeds",
    "zigzag_count",
]
