"""The robot: exact arcs under a held command, and the non-ideal velocity loop.

``docs/model.md §4``: the ideal loop integrates each held ``(v, ω)`` exactly
(``arc_step``); the non-ideal loop runs a computed-torque wheel-speed loop on
the dynamics of Eq. 5 (``advance``). These pure primitives check nothing;
``check_stability`` tells whether the sub-steps are short enough.
"""

from wmr_jax._src.model.dynamics import RobotState as RobotState
from wmr_jax._src.model.dynamics import arc_step as arc_step
from wmr_jax._src.model.dynamics import initial_state as initial_state
from wmr_jax._src.model.dynamics import sin_cos as sin_cos
from wmr_jax._src.model.dynamics import sinc as sinc
from wmr_jax._src.model.robots import read_robot as read_robot
from wmr_jax._src.model.robots import robot_preset as robot_preset
from wmr_jax._src.model.velocity_loop import DEFAULT_SUBSTEPS as DEFAULT_SUBSTEPS
from wmr_jax._src.model.velocity_loop import advance as advance
from wmr_jax._src.model.velocity_loop import body_acceleration as body_acceleration
from wmr_jax._src.model.velocity_loop import check_stability as check_stability
from wmr_jax._src.model.velocity_loop import inertia as inertia
from wmr_jax._src.model.velocity_loop import kinetic_energy as kinetic_energy
from wmr_jax._src.model.velocity_loop import limit_wheels as limit_wheels
from wmr_jax._src.model.velocity_loop import wheel_torques as wheel_torques
