"""The non-ideal loop's faster paths equal its general one (docs/model.md §4, §7).

For a concrete robot whose integral gain or centre-of-mass offset is zero,
the entry points leave those terms out, and when ``V_max dt / (L substeps)``
bounds every sub-step's turn they skip the angle reduction of the arcs.
Inside a caller's ``jit`` the robot and ``dt`` are traced and the general
loop runs: the two must agree to rounding, and the bound must be respected.
"""

import warnings

import jax
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w

REFS = random_refs(23, 64)
GAINS = w.Gains(kr=100.0)


def _general(refs, robot, dt, **kwargs):
    """The same run with ``robot`` and ``dt`` traced: no term can be left out."""

    @jax.jit
    def run(robot, dt):
        return w.final_poses(refs, GAINS, robot=robot, dt=dt, velocity="nonideal", **kwargs)

    return np.asarray(run(robot, dt))


@pytest.mark.parametrize(
    "robot",
    [
        w.Robot(),  # proportional loop, centre of mass on the axle
        w.Robot(com_offset=0.8),  # Coriolis terms, no integral
        w.Robot(integral_gain=2000.0),  # integral, no Coriolis terms
    ],
    ids=["plain", "offset", "integral"],
)
def test_specialised_loop_equals_general_loop(robot):
    fast = np.asarray(w.final_poses(REFS, GAINS, robot=robot, velocity="nonideal", steps=90))
    general = _general(REFS, robot, 0.033, steps=90)
    # The hard law switches regions on exact comparisons, so a rounding
    # difference could in principle flip one sample; none does here.
    np.testing.assert_allclose(fast, general, rtol=0, atol=1e-9)


def test_large_turns_per_substep_keep_the_reduced_arc():
    # A narrow robot with strong motors and a fast heading gain, sampled
    # slowly: V_max h / L = 125 * 0.025 / 0.6 = 5.2, and sub-steps do turn
    # by more than π/2 (beyond the small-angle kernels), so the arcs must
    # reduce their angles.
    robot = w.Robot(half_track=0.6, torque_max=1e4)
    gains = w.Gains(kr=40.0, k_theta=200.0)
    refs = np.array([[2.0, 0.0, 3.0], [-1.0, 1.0, -2.5]])
    kwargs = dict(robot=robot, dt=0.025, substeps=1, steps=30, velocity="nonideal")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", w.SamplingWarning)  # k_θ dt = 5, on purpose
        traj = w.batch_rollout(refs, gains, **kwargs)
        exps = [w.reference_rollout(ref, gains, **kwargs) for ref in refs]
    turns = np.abs(np.diff(np.asarray(traj.poses)[:, :, 2], axis=1))
    assert turns.max() > np.pi / 2
    for i, exp in enumerate(exps):
        np.testing.assert_allclose(np.asarray(traj.poses[i]), exp["poses"], rtol=0, atol=1e-9)


def _program_size(fn, *args):
    """Number of operations in the traced program of ``fn(*args)``, sub-programs included."""

    def size(jaxpr):
        total = 0
        for eqn in jaxpr.eqns:
            total += 1
            for param in eqn.params.values():
                inner = getattr(param, "jaxpr", param)
                if hasattr(inner, "eqns"):
                    total += size(inner)
        return total

    return size(jax.make_jaxpr(fn)(*args).jaxpr)


def test_the_fast_paths_are_taken_only_where_the_terms_vanish():
    refs = REFS[:4]

    def concrete(robot):  # the robot is a constant of the trace: the entry point sees its values
        return _program_size(
            lambda: w.final_poses(refs, GAINS, robot=robot, velocity="nonideal", steps=5)
        )

    def traced(robot):  # the robot is traced: the general loop
        return _program_size(
            lambda r: w.final_poses(refs, GAINS, robot=r, velocity="nonideal", steps=5), robot
        )

    plain = concrete(w.Robot())
    # Both terms kept; only the sub-steps' small turns (V_max h / L ≤ π/2) are used.
    full = concrete(w.Robot(com_offset=0.8, integral_gain=2000.0))
    assert plain < concrete(w.Robot(com_offset=0.8)) < full < traced(w.Robot())
    assert plain < concrete(w.Robot(integral_gain=2000.0)) < full
    # One robot per pose: a term stays if any pose's robot needs it.
    n = len(refs)
    mixed = w.Robot(com_offset=np.array([0.0, 0.8, 0.0, 0.0]), integral_gain=np.full(n, 2000.0))
    assert concrete(mixed) == full
    zeros = w.Robot(com_offset=np.zeros(n), integral_gain=np.zeros(n))
    assert concrete(zeros) == plain
