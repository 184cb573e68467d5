"""The controller family: the Shim–Sung law and two polar-coordinate baselines.

Importing this package registers every controller by name. The baselines
import the Shim–Sung error coordinates, so Shim–Sung is registered first.
"""

from wmr_jax._src.model.controllers.aicardi import AICARDI as AICARDI
from wmr_jax._src.model.controllers.astolfi import ASTOLFI as ASTOLFI
from wmr_jax._src.model.controllers.base import Controller as Controller
from wmr_jax._src.model.controllers.base import controller_names as controller_names
from wmr_jax._src.model.controllers.base import get_controller as get_controller
from wmr_jax._src.model.controllers.base import register_controller as register_controller
from wmr_jax._src.model.controllers.base import registered_names as registered_names
from wmr_jax._src.model.controllers.schedule import SCHEDULE as SCHEDULE
from wmr_jax._src.model.controllers.schedule import ScheduleParams as ScheduleParams
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG as SHIM_SUNG
