"""The law's and the baselines' boundaries, exactly where docs/model.md puts them.

Each boundary is probed on both sides and on the line itself, with error
coordinates set by hand, so that a ``≤`` turned into ``<`` (or a strict test
made loose) changes an answer.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import controllers


def _error(cos_phi, r=10.0):
    """Error coordinates with a given ``cos φ_e`` (``sin φ_e ≥ 0``) and a zero heading error."""
    cos_phi = float(cos_phi)
    return w.controllers.PolarError(
        jnp.float64(r),
        jnp.float64(cos_phi),
        jnp.float64(math.sqrt(max(0.0, 1.0 - cos_phi**2))),
        jnp.float64(1.0),
        jnp.float64(0.0),
    )


@pytest.mark.parametrize("phi_m", [math.radians(70.0), math.radians(45.0), 0.3])
def test_the_direction_flag_is_loose_ahead_and_strict_behind(phi_m):
    """§3.2: ``d = 1`` if ``|φ_e| ≤ Φ_m``; ``d = −1`` only if ``|φ_e| > π − Φ_m``."""
    edge = float(jnp.cos(jnp.float64(phi_m)))  # cos Φ_m as the law computes it
    up, down = np.nextafter(edge, 2.0), np.nextafter(edge, -2.0)
    cases = {
        up: 1,  # just inside the drive cone
        edge: 1,  # on its edge: |φ_e| = Φ_m drives forwards
        down: 0,  # just outside: a side sector, turn in place
        -down: 0,  # just short of the rear cone
        -edge: 0,  # on its edge: |φ_e| = π − Φ_m still turns (strict)
        -up: -1,  # just inside the rear cone
    }
    for cos_phi, want in cases.items():
        d = controllers.direction_flag(_error(cos_phi), jnp.float64(phi_m))
        assert float(d) == want, (cos_phi, want, float(d))


def test_region_zero_includes_its_radius_and_region_one_excludes_its_outer_one():
    """§3.3: Region 0 for ``r_e ≤ R_e``; Region 1 for ``r_e < R_a``; Region 2 beyond."""
    gains = w.Gains(r_e=1.5, r_a=12.0, r_m=20.0)
    pose = np.zeros(3)
    edges = ((1.5, 0), (np.nextafter(1.5, 2.0), 1), (np.nextafter(12.0, 0.0), 1), (12.0, 2))
    for r, want in edges:
        ref = np.array([r, 0.0, 0.0])  # straight ahead: d = 1
        label = w.controllers.region_label(w.controllers.polar_error(pose, ref), gains)
        assert int(label) == want, (r, want)


@pytest.mark.parametrize(
    ("name", "params", "rate"),
    [
        ("aicardi", w.controllers.AicardiGains(k=6.0), 6.0),
        ("astolfi-corke", w.controllers.AstolfiGains(), None),
    ],
)
@pytest.mark.parametrize("heading_deg", [30.0, -100.0, 179.0])
def test_the_polar_baselines_only_turn_to_the_heading_at_the_goal(name, params, rate, heading_deg):
    """§3.8: within 1e-3 cm, ``v = 0`` and ``ω = k θ_e`` (Aicardi) or ``k_α θ_e`` (Astolfi)."""
    rate = params.k_alpha if rate is None else rate
    control = controllers.get_controller(name).command
    theta_e = math.radians(heading_deg)
    pose = np.array([5.0, -3.0, 0.4])
    ref = pose + np.array([6e-4, 5e-4, theta_e])  # 7.8e-4 cm away: inside the floor
    v, omega = control(jnp.asarray(pose), jnp.asarray(ref), params)
    assert float(v) == 0.0
    assert float(omega) == pytest.approx(rate * theta_e, rel=1e-12)
    # Just beyond the floor the law drives again.
    far = pose + np.array([1.2e-3, 0.0, theta_e])
    v, _ = control(jnp.asarray(pose), jnp.asarray(far), params)
    assert float(v) != 0.0


@pytest.mark.parametrize("tol_theta", [math.radians(5.0), 0.1, 0.3, 1.0])
def test_a_heading_exactly_tol_theta_off_is_arrived_and_one_ulp_more_is_not(tol_theta):
    # docs/model.md §6: |θ̄_e| ≤ tol_θ. Judged through cosines, 5° and 0.1 rad
    # fell outside (cos rounded below cos tol) while 0.3 and 1 rad fell inside.
    ref = np.zeros(3)
    poses = np.array([[0.0, 0.0, tol_theta], [0.0, 0.0, -tol_theta]])
    beyond = np.array([[0.0, 0.0, np.nextafter(tol_theta, 2.0)]])
    assert np.all(w.studies.arrived(poses, ref, tol_theta=tol_theta))
    assert not np.any(w.studies.arrived(beyond, ref, tol_theta=tol_theta))
    # The arrival time and the streamed metrics of a run that sits there agree.
    traj = w.Trajectory(
        np.tile(poses[:1], (4, 1)), np.zeros(3), np.zeros(3), np.zeros(3, np.int32),
        np.zeros((3, 2)), np.zeros(3),
    )  # fmt: skip
    assert float(w.arrival_time(traj, ref, dt=0.1, tol_theta=tol_theta)) == 0.1
