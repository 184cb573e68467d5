"""The JAX rollouts against the independent NumPy reference, in float64."""

import math

import jax
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w

# Both implementations do the same float64 arithmetic in a different order
# (angles and atan2 vs cosines); over 150 steps the differences stay at the
# 1e-13 level. 1e-9 cm is the agreement the project promises.
POSE_ATOL = 1e-9

GAIN_SETS = [
    w.Gains(),
    w.Gains(kr=60.0),
    w.Gains(kr=90.0, k_theta=6.0, phi_m=math.radians(50), r_m=30.0, r_a=12.0, r_e=0.5, alpha=0.1),
    w.Gains(kr=40.0, k_theta=15.0, phi_m=math.radians(85), r_m=10.0, r_a=10.0, r_e=2.0, alpha=0.45),
]


@pytest.mark.parametrize("gains", GAIN_SETS, ids=["fig7", "fig10", "tight", "loose"])
def test_batch_rollout_matches_reference(gains):
    rng = np.random.default_rng(7)
    refs = random_refs(7, 200)
    inits = np.concatenate(
        [rng.uniform(-20, 20, (200, 2)), rng.uniform(-math.pi, math.pi, (200, 1))], axis=1
    )
    # One host copy: indexing device arrays pose by pose would dominate the test.
    traj = jax.tree.map(np.asarray, w.batch_rollout(refs, gains, init=inits, steps=150))
    worst = 0.0
    for i in range(len(refs)):
        ref_traj = w.reference_rollout(refs[i], gains, init=inits[i], steps=150)
        np.testing.assert_array_equal(np.asarray(traj.region[i]), ref_traj["region"])
        for field in ("poses", "v", "omega", "wheel_speeds", "distance"):
            np.testing.assert_allclose(
                np.asarray(getattr(traj, field)[i]), ref_traj[field], rtol=0, atol=POSE_ATOL
            )
        worst = max(worst, float(np.abs(np.asarray(traj.poses[i]) - ref_traj["poses"]).max()))
    assert worst < POSE_ATOL


def test_paper_references_match(paper_refs):
    for ref in paper_refs:
        for kr in (60.0, 120.0):
            traj = w.rollout(ref, w.Gains(kr=kr))
            expected = w.reference_rollout(ref, w.Gains(kr=kr))
            np.testing.assert_allclose(np.asarray(traj.poses), expected["poses"], atol=POSE_ATOL)
            np.testing.assert_array_equal(np.asarray(traj.region), expected["region"])


def test_diagnostics_match_reference():
    rng = np.random.default_rng(3)
    refs = random_refs(3, 300, r_min=0.0, r_max=40.0)
    poses = np.zeros_like(refs)
    poses[:, 2] = rng.uniform(-math.pi, math.pi, len(refs))
    for gains in GAIN_SETS:
        diag = jax.tree.map(np.asarray, w.controllers.control_diagnostics(poses, refs, gains))
        for i in range(len(refs)):
            exp = w.studies.reference_diagnostics(poses[i], refs[i], gains)
            assert int(diag.region[i]) == exp["region"]
            for key in ("v", "omega", "d", "eps", "lyapunov", "r_e", "phi_e", "theta_e"):
                # Same law, float64; a few ulps of reordering.
                assert float(getattr(diag, key)[i]) == pytest.approx(exp[key], abs=1e-11), key


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"gains": w.Gains(kr=-60.0)}, "gains.kr = -60.0"),
        ({"gains": w.Gains(kr=[60.0, 70.0])}, r"gains.kr has shape \(2,\)"),
        ({"dt": 0.0}, "dt = 0.0"),
        ({"steps": -1}, "steps = -1"),
        ({"ref": [30.0, 30.0]}, r"ref has shape \(2,\)"),
        ({"init": [float("nan"), 0.0, 0.0]}, r"init = \[nan, 0.0, 0.0\]"),
        # Beyond 1e153 cm the squared distance overflows float64 (was an OverflowError).
        ({"ref": [1e160, 0.0, 0.0]}, r"ref = \[1e\+160, 0.0, 0.0\] .* \|x\|, \|y\| <= 1e\+153 cm"),
        ({"init": [0.0, -1e155, 0.0]}, r"init = .* \|x\|, \|y\| <= 1e\+153 cm"),
        ({"robot": w.Robot(half_track=0.0)}, "robot.half_track = 0.0"),
        ({"velocity": "nonideal", "substeps": 0}, "substeps = 0"),
        ({"velocity": "nonideal", "wheel_limit": "bogus"}, "wheel_limit = 'bogus'"),
        ({"velocity": "nonideal", "robot": w.Robot(speed_gain=1e4)}, "substeps = 10"),
    ],
)
def test_the_reference_checks_its_inputs_as_rollout_does(kwargs, message):
    args = {"ref": [30.0, 30.0, 0.0], "steps": 3, **kwargs}
    with pytest.raises(ValueError, match=message):
        w.reference_rollout(args.pop("ref"), **args)


def test_the_reference_law_refuses_positions_whose_distance_overflows():
    with pytest.raises(ValueError, match=r"pose = .* allowed: finite numbers, \|x\|, \|y\| <= 1e"):
        w.studies.reference_control([1e200, 0.0, 0.0], [0.0, 0.0, 0.0], w.Gains())
    with pytest.raises(ValueError, match=r"ref = .* allowed: finite numbers, \|x\|, \|y\| <= 1e"):
        w.studies.reference_diagnostics([0.0, 0.0, 0.0], [0.0, -1e156, 0.0], w.Gains())
    # At the limit the law is still defined (and the distance finite).
    assert w.studies.reference_diagnostics([-1e153, 1e153, 0.0], [1e153, -1e153, 0.0], w.Gains())[
        "r_e"
    ] == pytest.approx(8**0.5 * 1e153)


def test_the_reference_checks_against_float64_whatever_jax_computes_in():
    # It computes in float64: a float32 session's limits would refuse these.
    with jax.enable_x64(False):
        with pytest.warns(w.SamplingWarning):  # as the JAX rollout warns in float64
            poses = w.reference_rollout([30.0, 30.0, 0.0], w.Gains(kr=1e40), steps=2)["poses"]
        assert np.isfinite(poses).all()
        assert np.isfinite(w.reference_rollout([30.0, 30.0, 0.0], dt=1e-40, steps=2)["poses"]).all()
        with pytest.raises(ValueError, match=r"gains.kr = 1e\+40 is beyond float32"):
            w.rollout(
                [30.0, 30.0, 0.0], w.Gains(kr=1e40), steps=2
            )  # the JAX loop does compute in float32


@pytest.mark.parametrize("kwargs", [{"gains": w.Gains(k_theta=1e30)}, {"dt": 1e30}])
def test_the_reference_refuses_a_run_beyond_what_float64_resolves(kwargs):
    """It returned headings of 1e28 rad where the JAX rollout refuses the run."""
    with pytest.warns(w.SamplingWarning), pytest.raises(ValueError) as info:
        w.reference_rollout([30.0, 30.0, 0.0], steps=5, **kwargs)
    assert str(info.value).startswith("the run left the range float64 resolves")
    assert "heading beyond 1e+12 rad" in str(info.value)
    with jax.enable_x64(True), pytest.warns(w.SamplingWarning), pytest.raises(ValueError):
        w.rollout([30.0, 30.0, 0.0], steps=5, **kwargs)


def test_the_reference_warns_where_rollout_warns_and_runs_on():
    gains = w.Gains(k_theta=100.0)  # k_θ dt = 3.3: it cannot settle, and stays in range
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 3.3") as caught:
        w.reference_rollout([30.0, 30.0, 0.0], gains, steps=5)
    assert caught[0].filename == __file__  # at the caller, as rollout's
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 3.3"):
        w.rollout([30.0, 30.0, 0.0], gains, steps=5)
