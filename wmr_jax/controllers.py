"""The controller family and the building blocks of the Shim–Sung law.

``wmr_jax.controllers`` holds the ``Controller`` value type, its registry, the
three controllers (Shim–Sung, Aicardi et al. 1995, Astolfi/Corke) and, one
function per equation, the pieces of the Shim–Sung law (``docs/model.md §2–3``)
for users who build their own variants.
"""

from wmr_jax._src.model.controllers import AICARDI as AICARDI
from wmr_jax._src.model.controllers import ASTOLFI as ASTOLFI
from wmr_jax._src.model.controllers import SHIM_SUNG as SHIM_SUNG
from wmr_jax._src.model.controllers import Controller as Controller
from wmr_jax._src.model.controllers import get_controller as get_controller
from wmr_jax._src.model.controllers import register_controller as register_controller
from wmr_jax._src.model.controllers import registered_names as registered_names
from wmr_jax._src.model.controllers.aicardi import AicardiGains as AicardiGains
from wmr_jax._src.model.controllers.aicardi import aicardi_control as aicardi_control
from wmr_jax._src.model.controllers.astolfi import AstolfiGains as AstolfiGains
from wmr_jax._src.model.controllers.astolfi import astolfi_control as astolfi_control
from wmr_jax._src.model.controllers.polar import driving_error as driving_error
from wmr_jax._src.model.controllers.schedule import SCHEDULE as SCHEDULE
from wmr_jax._src.model.controllers.schedule import ScheduleParams as ScheduleParams
from wmr_jax._src.model.controllers.schedule import knot_radii as knot_radii
from wmr_jax._src.model.controllers.schedule import schedule_commands as schedule_commands
from wmr_jax._src.model.controllers.shim_sung import Diagnostics as Diagnostics
from wmr_jax._src.model.controllers.shim_sung import PolarError as PolarError
from wmr_jax._src.model.controllers.shim_sung import blend as blend
from wmr_jax._src.model.controllers.shim_sung import commands as commands
from wmr_jax._src.model.controllers.shim_sung import control as control
from wmr_jax._src.model.controllers.shim_sung import control_diagnostics as control_diagnostics
from wmr_jax._src.model.controllers.shim_sung import direction_flag as direction_flag
from wmr_jax._src.model.controllers.shim_sung import error_angles as error_angles
from wmr_jax._src.model.controllers.shim_sung import fold as fold
from wmr_jax._src.model.controllers.shim_sung import lyapunov as lyapunov
from wmr_jax._src.model.controllers.shim_sung import polar_error as polar_error
from wmr_jax._src.model.controllers.shim_sung import region_label as region_label
from wmr_jax._src.model.controllers.shim_sung import saturated_distance as saturated_distance
from wmr_jax._src.model.controllers.shim_sung import sgn as sgn
from wmr_jax._src.model.controllers.shim_sung import wheel_speeds as wheel_speeds
from wmr_jax._src.model.controllers.shim_sung import wrap_angle as wrap_angle
from wmr_jax._src.model.params import check_feasible as check_feasible
from wmr_jax._src.model.params import check_sampling as check_sampling
from wmr_jax._src.model.params import sampling_margins as sampling_margins
from wmr_jax._src.model.params import wheel_speed_bound as wheel_speed_bound
