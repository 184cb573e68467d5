"""wmr_jax: a differentiable, batched simulator of the Shim–Sung (2003) pose controller.

The curated surface: users import ``wmr_jax`` (and the families
``wmr_jax.controllers``, ``wmr_jax.dynamics``, ``wmr_jax.tuning``,
``wmr_jax.studies``, ``wmr_jax.report``, ``wmr_jax.export``), never the private
``wmr_jax._src``.
The model every function implements is ``docs/model.md``.
"""

from wmr_jax._src.checks import float_dtype as float_dtype
from wmr_jax._src.model.controllers import AICARDI as AICARDI
from wmr_jax._src.model.controllers import ASTOLFI as ASTOLFI
from wmr_jax._src.model.controllers import SHIM_SUNG as SHIM_SUNG
from wmr_jax._src.model.controllers import Controller as Controller
from wmr_jax._src.model.controllers import get_controller as get_controller
from wmr_jax._src.model.controllers import register_controller as register_controller
from wmr_jax._src.model.controllers import registered_names as registered_names
from wmr_jax._src.model.controllers.aicardi import AicardiGains as AicardiGains
from wmr_jax._src.model.controllers.astolfi import AstolfiGains as AstolfiGains
from wmr_jax._src.model.controllers.shim_sung import Diagnostics as Diagnostics
from wmr_jax._src.model.controllers.shim_sung import PolarError as PolarError
from wmr_jax._src.model.controllers.shim_sung import control as control
from wmr_jax._src.model.controllers.shim_sung import control_diagnostics as control_diagnostics
from wmr_jax._src.model.controllers.shim_sung import lyapunov as lyapunov
from wmr_jax._src.model.controllers.shim_sung import polar_error as polar_error
from wmr_jax._src.model.controllers.shim_sung import region_label as region_label
from wmr_jax._src.model.controllers.shim_sung import wheel_speeds as wheel_speeds
from wmr_jax._src.model.params import Gains as Gains
from wmr_jax._src.model.params import Robot as Robot
from wmr_jax._src.model.params import SamplingWarning as SamplingWarning
from wmr_jax._src.model.params import WheelSpeedWarning as WheelSpeedWarning
from wmr_jax._src.model.params import check_feasible as check_feasible
from wmr_jax._src.model.params import check_sampling as check_sampling
from wmr_jax._src.model.params import sampling_margins as sampling_margins
from wmr_jax._src.model.params import wheel_speed_bound as wheel_speed_bound
from wmr_jax._src.model.robots import ROBOTS as ROBOTS
from wmr_jax._src.model.robots import RobotUnitsWarning as RobotUnitsWarning
from wmr_jax._src.model.robots import load_robot as load_robot
from wmr_jax._src.model.robots import read_robot as read_robot
from wmr_jax._src.model.robots import robot_preset as robot_preset
from wmr_jax._src.oracle.reference import reference_control as reference_control
from wmr_jax._src.oracle.reference import reference_diagnostics as reference_diagnostics
from wmr_jax._src.oracle.reference import reference_rollout as reference_rollout
from wmr_jax._src.sim.loops import Options as Options
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R as DEFAULT_TOL_R
from wmr_jax._src.sim.metrics import DEFAULT_TOL_THETA as DEFAULT_TOL_THETA
from wmr_jax._src.sim.metrics import arrival_time as arrival_time
from wmr_jax._src.sim.metrics import arrived as arrived
from wmr_jax._src.sim.metrics import path_length as path_length
from wmr_jax._src.sim.metrics import region_time as region_time
from wmr_jax._src.sim.metrics import success_rate as success_rate
from wmr_jax._src.sim.metrics import zigzag_count as zigzag_count
from wmr_jax._src.sim.poses import EVAL_R_MAX as EVAL_R_MAX
from wmr_jax._src.sim.poses import EVAL_R_MIN as EVAL_R_MIN
from wmr_jax._src.sim.poses import HORIZON_S as HORIZON_S
from wmr_jax._src.sim.poses import PAPER_REFS_DEG as PAPER_REFS_DEG
from wmr_jax._src.sim.poses import horizon_steps as horizon_steps
from wmr_jax._src.sim.poses import paper_refs as paper_refs
from wmr_jax._src.sim.poses import sample_poses as sample_poses
from wmr_jax._src.sim.rollout import DEFAULT_DT as DEFAULT_DT
from wmr_jax._src.sim.rollout import Trajectory as Trajectory
from wmr_jax._src.sim.rollout import batch_rollout as batch_rollout
from wmr_jax._src.sim.rollout import final_poses as final_poses
from wmr_jax._src.sim.rollout import rollout as rollout
from wmr_jax._src.sim.sensing.estimators import EKFParams as EKFParams
from wmr_jax._src.sim.sensing.estimators import ObserverParams as ObserverParams
from wmr_jax._src.sim.sensing.loop import ClosedLoop as ClosedLoop
from wmr_jax._src.sim.sharding import ShardedBatch as ShardedBatch
from wmr_jax._src.sim.sharding import shard as shard
from wmr_jax._src.sim.sharding import unpad as unpad
from wmr_jax._src.sim.sharding import use_cpu_devices as use_cpu_devices
from wmr_jax._src.studies.optimal import TimeBounds as TimeBounds
from wmr_jax._src.studies.optimal import time_bounds as time_bounds
from wmr_jax._src.studies.sweep import SWEEP_FIELDS as SWEEP_FIELDS
from wmr_jax._src.studies.sweep import sweep as sweep
from wmr_jax._src.tuning.saved import load_tuned as load_tuned

__version__ = "0.1.0"

# The public families, imported on first use (wmr_jax.cli, say, after a plain
# ``import wmr_jax``): report, studies and tuning import optax or matplotlib,
# and cli every command, which ``import wmr_jax`` should not pay for.
_SUBMODULES = ("cli", "controllers", "dynamics", "export", "report", "studies", "tuning")

# Every name imported above as itself, and the families (tests/test_usability.py
# holds the list to the imports: a new export goes in both).
__all__ = [
    "float_dtype",
    "AICARDI",
    "ASTOLFI",
    "SHIM_SUNG",
    "Controller",
    "get_controller",
    "register_controller",
    "registered_names",
    "AicardiGains",
    "AstolfiGains",
    "Diagnostics",
    "PolarError",
    "control",
    "control_diagnostics",
    "lyapunov",
    "polar_error",
    "region_label",
    "wheel_speeds",
    "Options",
    "DEFAULT_TOL_R",
    "DEFAULT_TOL_THETA",
    "arrival_time",
    "arrived",
    "path_length",
    "region_time",
    "success_rate",
    "zigzag_count",
    "TimeBounds",
    "time_bounds",
    "Gains",
    "Robot",
    "SamplingWarning",
    "WheelSpeedWarning",
    "RobotUnitsWarning",
    "check_feasible",
    "check_sampling",
    "sampling_margins",
    "wheel_speed_bound",
    "EVAL_R_MAX",
    "EVAL_R_MIN",
    "HORIZON_S",
    "PAPER_REFS_DEG",
    "horizon_steps",
    "paper_refs",
    "sample_poses",
    "reference_control",
    "reference_diagnostics",
    "reference_rollout",
    "ROBOTS",
    "load_robot",
    "read_robot",
    "robot_preset",
    "DEFAULT_DT",
    "Trajectory",
    "batch_rollout",
    "final_poses",
    "rollout",
    "EKFParams",
    "ObserverParams",
    "ClosedLoop",
    "ShardedBatch",
    "shard",
    "unpad",
    "use_cpu_devices",
    "SWEEP_FIELDS",
    "sweep",
    "load_tuned",
    "cli",
    "controllers",
    "dynamics",
    "export",
    "report",
    "studies",
    "tuning",
]


def __getattr__(name: str):
    if name in _SUBMODULES:
        import importlib

        return importlib.import_module(f"wmr_jax.{name}")
    raise AttributeError(f"module 'wmr_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
