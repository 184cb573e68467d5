"""The tuner's feasible set (``tuning/parametrisation.py``) against its written definition.

The box is stated in the module's "choice" comment and ``docs/tuning.md``: the
wheel budget ``k_r + L k_θ`` spans ``[1e-3, 1 − 1e-4] V_max`` and the share
of it given to ``k_r`` spans ``[1e-3, 1 − 1e-3]``, both linear in ``u``;
``Φ_m`` spans ``[1e-3, π/2 − 1e-3]`` and ``α`` ``[1e-3, 0.5 − 1e-3]``,
linearly; ``R_m`` is log-uniform over 0.5–200 cm and ``R_a/R_m``, ``R_e/R_a``
log-uniform over 0.01–1. The expected gains below are computed from that text
with ``math``, one point at a time.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src.tuning import parametrisation as p

ROBOT = w.Robot(half_track=2.5, v_max=90.0)


def _lin(u, lo, hi):
    return lo + (hi - lo) * u


def _log(u, lo, hi):
    return math.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * u)


def _expected(u, half_track, v_max):
    budget = v_max * _lin(u[0], 1e-3, 1 - 1e-4)
    share = _lin(u[1], 1e-3, 1 - 1e-3)
    r_m = _log(u[4], 0.5, 200.0)
    r_a = r_m * _log(u[5], 0.01, 1.0)
    return {
        "kr": budget * share,
        "k_theta": budget * (1 - share) / half_track,
        "phi_m": _lin(u[2], 1e-3, math.pi / 2 - 1e-3),
        "r_m": r_m,
        "r_a": r_a,
        "r_e": r_a * _log(u[6], 0.01, 1.0),
        "alpha": _lin(u[3], 1e-3, 0.5 - 1e-3),
    }


def test_the_gain_fields_are_the_seven_of_the_law_in_order():
    assert p.GAIN_FIELDS == ("kr", "k_theta", "phi_m", "r_m", "r_a", "r_e", "alpha")
    assert p.PAPER_FEASIBLE_GAINS == w.Gains(kr=60.0, k_theta=10.0)


@pytest.mark.parametrize("robot", [None, ROBOT])
def test_gains_from_unit_is_the_written_box(robot):
    rng = np.random.default_rng(0)
    u = np.concatenate([rng.uniform(0, 1, (6, 7)), np.zeros((1, 7)), np.ones((1, 7))])
    gains = p.gains_from_unit(jnp.asarray(u), robot)
    half_track, v_max = (1.85, 125.0) if robot is None else (2.5, 90.0)
    for i, row in enumerate(u):
        want = _expected(row, half_track, v_max)
        for name in p.GAIN_FIELDS:
            assert float(getattr(gains, name)[i]) == pytest.approx(want[name], rel=1e-12), name


def test_the_corners_of_the_cube_are_the_ends_of_the_ranges():
    lo = p.gains_as_dict(p.gains_from_unit(jnp.zeros(7), ROBOT))
    hi = p.gains_as_dict(p.gains_from_unit(jnp.ones(7), ROBOT))
    assert lo["r_m"] == pytest.approx(0.5) and hi["r_m"] == pytest.approx(200.0)
    assert lo["r_a"] == pytest.approx(0.005) and hi["r_a"] == pytest.approx(200.0)
    assert lo["r_e"] == pytest.approx(5e-5) and hi["r_e"] == pytest.approx(200.0)
    assert lo["kr"] + 2.5 * lo["k_theta"] == pytest.approx(90.0 * 1e-3)
    assert hi["kr"] + 2.5 * hi["k_theta"] == pytest.approx(90.0 * (1 - 1e-4))
    assert lo["alpha"] == pytest.approx(1e-3) and hi["alpha"] == pytest.approx(0.499)
    assert lo["phi_m"] == pytest.approx(1e-3) and hi["phi_m"] == pytest.approx(math.pi / 2 - 1e-3)


def test_unit_from_gains_is_the_inverse_inside_and_clips_to_the_faces():
    u = np.array([0.2, 0.7, 0.4, 0.9, 0.35, 0.6, 0.15])
    gains = p.gains_from_unit(jnp.asarray(u), ROBOT)
    back = p.unit_from_gains(w.Gains(**p.gains_as_dict(gains)), ROBOT)
    np.testing.assert_allclose(back, u, rtol=1e-10)
    z = p.logits_from_gains(w.Gains(**p.gains_as_dict(gains)), ROBOT)
    np.testing.assert_allclose(z, [math.log(x / (1 - x)) for x in u], rtol=1e-9)
    # The paper's default gains sit on faces (R_a = R_m) and outside (k_r + L k_θ > V_max).
    paper = p.unit_from_gains(w.Gains(), None)
    budget = 120.0 + 1.85 * 10.0
    want = [
        (budget / 125.0 - 1e-3) / (1 - 1e-4 - 1e-3),
        (120.0 / budget - 1e-3) / (1 - 2e-3),
        (math.radians(70.0) - 1e-3) / (math.pi / 2 - 2e-3),
        (0.25 - 1e-3) / (0.5 - 2e-3),
        (math.log(20.0) - math.log(0.5)) / (math.log(200.0) - math.log(0.5)),
        1.0,
        (math.log(1 / 20) - math.log(0.01)) / (0 - math.log(0.01)),
    ]
    want = [min(max(x, 1e-3), 1 - 1e-3) for x in want]
    np.testing.assert_allclose(paper, want, rtol=1e-12)
    assert paper.dtype == np.float64 and paper.shape == (7,)


def test_gains_from_logits_is_gains_from_unit_of_the_sigmoid():
    z = np.array([-3.0, 0.0, 2.0, -0.5, 1.0, 40.0, -40.0])
    a = p.gains_as_dict(p.gains_from_logits(jnp.asarray(z), ROBOT))
    want = _expected([1 / (1 + math.exp(-x)) for x in z], 2.5, 90.0)
    for name in p.GAIN_FIELDS:
        assert a[name] == pytest.approx(want[name], rel=1e-12), name
    # Infinite logits are the faces of the cube: allowed.
    p.gains_from_logits(jnp.asarray([math.inf, -math.inf, 0, 0, 0, 0, 0]))


def test_both_problems_map_a_point_on_the_paper_robot_when_given_no_robot():
    """``from_unit`` of the fixed and the schedule problem: no robot, or None, is ``Robot()``."""
    from wmr_jax import tuning

    other = w.Robot(half_track=8.0, v_max=22.0)
    for problem in (tuning.FIXED, tuning.SCHEDULED):
        u = np.full(problem.dim, 0.5)
        paper = jax.tree.leaves(problem.from_unit(u, w.Robot()))
        for given in (problem.from_unit(u), problem.from_unit(u, None)):
            np.testing.assert_array_equal(jax.tree.leaves(given), paper)
        # The robot is used: another robot's budget gives other parameters.
        moved = jax.tree.leaves(problem.from_unit(u, other))
        assert any(not np.array_equal(a, b) for a, b in zip(moved, paper, strict=True))


def test_gains_as_dict_is_floats_in_field_order():
    d = p.gains_as_dict(w.Gains(kr=np.float32(3.5), r_e=jnp.asarray(0.5)))
    assert list(d) == list(p.GAIN_FIELDS)
    assert d["kr"] == 3.5 and d["r_e"] == 0.5 and all(type(v) is float for v in d.values())


@pytest.mark.parametrize(
    "u, message",
    [
        (np.zeros(6), r"^u has shape \(6,\); allowed: \(\.\.\., 7\)$"),
        (0.5, r"^u has shape \(\); allowed: \(\.\.\., 7\)$"),
        (np.full(7, 1.0 + 1e-9), r"^u = .* is not allowed; allowed: numbers in \[0, 1\]$"),
        (np.full(7, -1e-9), r"^u = .* is not allowed; allowed: numbers in \[0, 1\]$"),
        (np.full(7, math.nan), r"^u = .* is not allowed; allowed: numbers in \[0, 1\]$"),
        ("x", r"^u .*real numbers of shape \(\.\.\., 7\)"),
    ],
)
def test_a_point_outside_the_cube_is_refused(u, message):
    with pytest.raises(ValueError, match=message):
        p.gains_from_unit(u)


@pytest.mark.parametrize(
    "z, message",
    [
        (np.zeros((2, 8)), r"^z has shape \(2, 8\); allowed: \(\.\.\., 7\)$"),
        (np.full(7, math.nan), r"^z = .* is not allowed; allowed: real numbers \(not NaN\)$"),
    ],
)
def test_logits_that_are_no_point_are_refused(z, message):
    with pytest.raises(ValueError, match=message):
        p.gains_from_logits(z)


def test_the_edges_of_the_cube_are_allowed():
    p.gains_from_unit(np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.5]))


def test_paper_feasible_gains_scale_both_gains_to_the_budget_of_a_slow_robot():
    # The paper robot and one whose budget is exactly 60 + 10 L keep the paper's gains.
    assert p.paper_feasible_gains() is p.PAPER_FEASIBLE_GAINS
    exact = w.Robot(half_track=2.0, v_max=80.0)  # 60 + 2 · 10 = 80
    assert p.paper_feasible_gains(exact) is p.PAPER_FEASIBLE_GAINS
    crawler = w.Robot(half_track=3.0, v_max=0.3)  # slow on purpose
    for robot in (w.Robot(v_max=50.0), crawler):
        g = p.paper_feasible_gains(robot)
        L, v_max = float(robot.half_track), float(robot.v_max)
        scale = v_max / (60.0 + 10.0 * L)
        assert float(g.kr) == pytest.approx(60.0 * scale, rel=1e-14)
        assert float(g.k_theta) == pytest.approx(10.0 * scale, rel=1e-14)
        assert float(g.kr) + L * float(g.k_theta) <= v_max  # within budget, to the ulp
        assert float(g.kr) / float(g.k_theta) == pytest.approx(6.0, rel=1e-14)
        assert g.phi_m == w.Gains().phi_m and g.alpha == w.Gains().alpha


def test_paper_feasible_gains_step_the_scale_down_when_rounding_overshoots():
    """Some robots' budgets are overshot by one ulp at the exact scale."""
    hit = 0
    for v_max in np.linspace(1.0, 70.0, 400):
        robot = w.Robot(half_track=1.85, v_max=float(v_max))
        scale = float(v_max) / (60.0 + 18.5)
        hit += 60.0 * scale + 1.85 * (10.0 * scale) > v_max
        g = p.paper_feasible_gains(robot)
        assert float(g.kr) + 1.85 * float(g.k_theta) <= v_max
        assert float(g.kr) + 1.85 * float(g.k_theta) == pytest.approx(v_max, rel=1e-14)
    assert hit > 0  # the loop is exercised


def test_paper_feasible_gains_refuse_no_robot():
    with pytest.raises(ValueError, match="v_max"):
        p.paper_feasible_gains(w.Robot(v_max=-1.0))
    with pytest.raises(ValueError) as err:
        p.paper_feasible_gains(w.Robot(v_max=np.array([100.0, 50.0])))
    assert str(err.value) == (
        "robot.v_max has shape (2,); allowed: one robot (a number per field) for the paper's "
        "feasible gains"
    )


def test_paper_feasible_gains_use_the_largest_scale_within_budget():
    """Docstring: the scale ``V_max / (60 + 10 L)``, stepped down an ulp at a time while
    ``k_r + L k_θ`` rounds above ``V_max``; so never a smaller scale than needed."""
    exact = over = 0
    for v_max in np.linspace(1.0, 70.0, 400):
        v_max = float(v_max)
        scale = v_max / 78.5
        exact += 60.0 * scale + 1.85 * (10.0 * scale) == v_max
        while 60.0 * scale + 1.85 * (10.0 * scale) > v_max:
            over += 1
            scale = math.nextafter(scale, 0.0)
        g = p.paper_feasible_gains(w.Robot(half_track=1.85, v_max=v_max))
        assert (float(g.kr), float(g.k_theta)) == (60.0 * scale, 10.0 * scale), v_max
    assert exact > 0 and over > 0  # both cases are met


def test_points_pass_traced_into_jit_and_give_the_same_gains():
    z = np.array([-3.0, 0.0, 2.0, -0.5, 1.0, 4.0, -4.0])
    traced = jax.jit(lambda z: p.gains_from_logits(z, ROBOT))(jnp.asarray(z))
    eager = p.gains_from_logits(jnp.asarray(z), ROBOT)
    for name in p.GAIN_FIELDS:
        assert float(getattr(traced, name)) == pytest.approx(float(getattr(eager, name)), rel=1e-12)


def test_gains_below_the_box_are_moved_onto_its_lower_faces():
    tiny = w.Gains(kr=1e-6, k_theta=1e-3, phi_m=1e-5, r_m=0.01, r_a=1e-5, r_e=1e-9, alpha=1e-6)
    np.testing.assert_array_equal(p.unit_from_gains(tiny), np.full(7, 1e-3))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # A negative or NaN budget gave negative or NaN gains, L = 0 gave k_θ = inf.
        (lambda: p.gains_from_unit(np.full(7, 0.5), w.Robot(v_max=-1.0)), r"robot.v_max = -1.0"),
        (lambda: p.gains_from_logits(np.zeros(7), w.Robot(v_max=math.nan)), r"robot.v_max = nan"),
        (lambda: p.gains_from_unit(np.full(7, 0.5), w.Robot(half_track=0.0)), r"robot.half_track"),
        (lambda: p.unit_from_gains(w.Gains(), w.Robot(v_max=math.nan)), r"robot.v_max = nan"),
        (
            lambda: p.gains_from_unit(np.full(7, 0.5), "paper"),
            r"robot = 'paper' is not allowed; allowed: a Robot \(wmr_jax.load_robot\('paper'\)",
        ),
        (
            lambda: p.gains_from_unit(np.full(7, 0.5), w.Robot(v_max=[100.0, 120.0])),
            r"robot.v_max has shape \(2,\); allowed: one robot",
        ),
        # A batch raised "only 0-dimensional arrays can be converted".
        (lambda: p.gains_as_dict(w.Gains(kr=[1.0, 2.0])), r"gains.kr has shape \(2,\); allowed"),
        (lambda: p.logits_from_gains(w.Gains(kr=[1.0, 2.0])), r"gains.kr has shape \(2,\)"),
        (lambda: p.gains_as_dict(w.Gains(kr=-1.0)), r"gains.kr = -1.0 is not allowed"),
        (lambda: p.gains_as_dict(None), r"gains is a NoneType; allowed: a wmr_jax.Gains"),
    ],
)
def test_the_maps_refuse_a_robot_or_gains_they_cannot_map(call, message):
    with pytest.raises(ValueError, match=rf"^{message}") as info:
        call()
    assert "\n" not in str(info.value)


def test_a_traced_robot_is_mapped_unchecked():
    """Inside jit the robot's fields are tracers: mapped as given, checked by the caller."""
    robot = w.Robot(v_max=100.0)
    direct = p.gains_from_unit(np.full(7, 0.5), robot)
    traced = jax.jit(lambda r: p.gains_from_unit(np.full(7, 0.5), r))(robot)
    assert float(traced.kr) == pytest.approx(float(direct.kr), rel=1e-12)
