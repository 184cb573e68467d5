"""wmr_jax: a differentiable, batched simulator of the Shim–Sung (2003) pose controller.

The names here are the whole first screen (``docs/model.md`` is the model):

* the robot and the gains: ``Robot`` (cm, kg, s), ``Gains``, ``load_robot``
  (a preset of ``ROBOTS`` or a JSON / ROS YAML file);
* the law: ``control``; other controllers: ``Controller``, ``get_controller``,
  ``register_controller``;
* runs: ``rollout`` (one pose), ``batch_rollout`` and ``final_poses`` (many),
  ``Trajectory``, ``ClosedLoop`` (a law with an estimator), ``DEFAULT_DT``;
  ``sweep`` streams a large batch to a folder; ``shard`` / ``unpad`` spread a
  batch over devices;
* poses and measures: ``sample_poses``, ``paper_refs``, ``arrival_time``,
  ``success_rate``;
* the NumPy oracle: ``reference_rollout``; tuned gains: ``load_tuned``;
* warnings: ``WheelSpeedWarning``, ``SamplingWarning``, ``RobotUnitsWarning``,
  ``HeadingUnitsWarning``.

The rest lives in the families, imported on first use: ``controllers`` (the
law's building blocks, the baselines, feasibility checks), ``dynamics`` (the
robot's primitives, presets and files), ``studies`` (experiments, metrics,
pose sets, the oracle's law, bounds), ``tuning``, ``report``, ``export``
(C code) and ``cli``. ``wmr_jax._src`` is private.
"""

from wmr_jax._src.checks import HeadingUnitsWarning as HeadingUnitsWarning
from wmr_jax._src.model.controllers import Controller as Controller
from wmr_jax._src.model.controllers import get_controller as get_controller
from wmr_jax._src.model.controllers import register_controller as register_controller
from wmr_jax._src.model.controllers.shim_sung import control as control
from wmr_jax._src.model.params import Gains as Gains
from wmr_jax._src.model.params import Robot as Robot
from wmr_jax._src.model.params import SamplingWarning as SamplingWarning
from wmr_jax._src.model.params import WheelSpeedWarning as WheelSpeedWarning
from wmr_jax._src.model.robots import ROBOTS as ROBOTS
from wmr_jax._src.model.robots import RobotUnitsWarning as RobotUnitsWarning
from wmr_jax._src.model.robots import load_robot as load_robot
from wmr_jax._src.oracle.reference import reference_rollout as reference_rollout
from wmr_jax._src.sim.metrics import arrival_time as arrival_time
from wmr_jax._src.sim.metrics import success_rate as success_rate
from wmr_jax._src.sim.poses import paper_refs as paper_refs
from wmr_jax._src.sim.poses import sample_poses as sample_poses
from wmr_jax._src.sim.rollout import DEFAULT_DT as DEFAULT_DT
from wmr_jax._src.sim.rollout import Trajectory as Trajectory
from wmr_jax._src.sim.rollout import batch_rollout as batch_rollout
from wmr_jax._src.sim.rollout import final_poses as final_poses
from wmr_jax._src.sim.rollout import rollout as rollout
from wmr_jax._src.sim.sensing.loop import ClosedLoop as ClosedLoop
from wmr_jax._src.sim.sharding import shard as shard
from wmr_jax._src.sim.sharding import unpad as unpad
from wmr_jax._src.studies.sweep import sweep as sweep
from wmr_jax._src.tuning.saved import load_tuned as load_tuned

__version__ = "0.1.0"

# The public families, imported on first use: report, studies and tuning import
# optax or matplotlib, and cli every command, which ``import wmr_jax`` should not pay for.
_SUBMODULES = ("cli", "controllers", "dynamics", "export", "report", "studies", "tuning")

# Every name imported above as itself, and the families.
__all__ = sorted({name for name in dir() if not name.startswith("_")} | set(_SUBMODULES))


def __getattr__(name: str):
    if name in _SUBMODULES:
        import importlib

        return importlib.import_module(f"wmr_jax.{name}")
    raise AttributeError(f"module 'wmr_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
