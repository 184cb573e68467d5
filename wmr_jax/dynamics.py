"""The robot: exact arcs under a held command, and the non-ideal velocity loop.

``docs/model.md §4``: the ideal loop integrates each held ``(v, ω)`` exactly
(``arc_step``); the non-ideal loop runs a computed-torque wheel-speed loop on
the Euler–Lagrange dynamics of Eq. 5 with wheel limits (``advance``). Called
with values, each function checks them first; inside a caller's ``jit`` or
``grad`` it runs as it is.
"""

from wmr_jax._src.dynamics import RobotState as RobotState
from wmr_jax._src.dynamics_checked import advance as advance
from wmr_jax._src.dynamics_checked import arc_step as arc_step
from wmr_jax._src.dynamics_checked import body_acceleration as body_acceleration
from wmr_jax._src.dynamics_checked import check_stability as check_stability
from wmr_jax._src.dynamics_checked import inertia as inertia
from wmr_jax._src.dynamics_checked import initial_state as initial_state
from wmr_jax._src.dynamics_checked import kinetic_energy as kinetic_energy
from wmr_jax._src.dynamics_checked import limit_wheels as limit_wheels
from wmr_jax._src.dynamics_checked import sin_cos as sin_cos
from wmr_jax._src.dynamics_checked import sinc as sinc
from wmr_jax._src.dynamics_checked import wheel_torques as wheel_torques
from wmr_jax._src.velocity_loop import DEFAULT_SUBSTEPS as DEFAULT_SUBSTEPS
