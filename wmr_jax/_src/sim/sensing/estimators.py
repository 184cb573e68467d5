"""Pose estimators of the sensed loop (docs/model.md §9): an observer and an extended Kalman filter.

Each period the loop predicts the estimate on the ideal robot's arc; the
estimator corrects it toward the measurement (``OBSERVER`` by gains in
``[0, 1]``, ``EKF`` by the Kalman gain). Latency compensation is the loop's.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    Parameters,
    check_bool,
    described,
    float_dtype,
    is_traced,
    real_array,
    require,
    require_one_batch_size,
    require_representable,
)
from wmr_jax._src.model.controllers.base import (
    Pluggable,
    call_error,
    check_registry_name,
    require_pytree,
)
from wmr_jax._src.model.controllers.schedule import table_at
from wmr_jax._src.model.dynamics import sin_cos
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import motion
from wmr_jax._src.sim.sensing.disturbances import Measurement

OBSERVER_KNOTS = 6  # knots per gain table by default
# The last knot, cm: the gains matter near the goal, where the law is most
# sensitive to noise; beyond it they are constant.
OBSERVER_R = 20.0


def observer_radii(knots: int) -> np.ndarray:
    """Return the distance of each gain knot, cm: ``OBSERVER_R (k / (K − 1))²``."""
    return OBSERVER_R * (np.arange(knots) / (knots - 1)) ** 2


# choice: hand-set tables, low at the goal (where noise would move the robot
# back and forth) up to 0.7 beyond about 7 cm; tuned tables replace them.
_DEFAULT_GAINS = (0.05, 0.1, 0.4, 0.7, 0.7, 0.7)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ObserverParams(Parameters):
    """Gains of the observer (docs/model.md §9).

    Attributes:
        position: gain toward the measured position, in ``[0, 1]``: a
            constant, or a tuple (or list) of ``K ≥ 2`` knots at
            ``observer_radii(K)`` cm (linear between). An array is one
            constant per run (a batch axis), not a table.
        heading: gain toward the measured heading, likewise.
        compensate: static; hand the law the estimate rolled forward over the
            commands in flight (docs/model.md §9).
    """

    position: Any = _DEFAULT_GAINS
    heading: Any = _DEFAULT_GAINS
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})
    _TABLES = ("position", "heading")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EKFParams(Parameters):
    """Covariances of the extended Kalman filter (docs/model.md §9).

    Attributes:
        wheel_error: standard deviation of each wheel's travel over a period,
            relative to that travel (odometry error), ``> 0``.
        sigma_xy: standard deviation of the measured x and y, cm, ``> 0``.
        sigma_theta: standard deviation of the measured heading, rad, ``> 0``.
        compensate: static; as in ``ObserverParams``.
    """

    wheel_error: Any = 0.03
    sigma_xy: Any = 0.5
    sigma_theta: Any = math.radians(1.0)
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})


def _check_values(name: str, value: Any, ok: Callable, allowed: str, sizes: dict) -> None:
    """Check one concrete field (a scalar or one batch axis); note its batch size in ``sizes``."""
    if is_traced(value):
        return
    arr = real_array(name, value, allowed)
    if arr.ndim > 1:
        raise ValueError(f"{name} has shape {arr.shape}; allowed: a scalar or one batch axis")
    require(name, arr, np.isfinite(arr) & ok(arr), allowed)
    require_representable(name, arr, tiny_ok=True)
    if arr.ndim:
        sizes[name] = arr.shape[0]


def _check_kind(params: Any, kind: type, prefix: str) -> None:
    """Refuse parameters of another estimator; check the static ``compensate`` flag."""
    if not isinstance(params, kind):
        raise ValueError(
            f"{prefix} is a {type(params).__name__}; allowed: a wmr_jax.studies.{kind.__name__}"
        )
    check_bool(f"{prefix}.compensate", params.compensate)


def validate_observer(params: ObserverParams, prefix: str = "estimator") -> ObserverParams:
    """Check an ``ObserverParams``; return it unchanged (``ValueError`` naming the field)."""
    _check_kind(params, ObserverParams, prefix)
    sizes = {}
    for name in ("position", "heading"):
        table = getattr(params, name)
        entries = table if isinstance(table, tuple) else (table,)
        if isinstance(table, tuple) and not 2 <= len(table) <= 50:
            raise ValueError(
                f"{prefix}.{name} has {len(table)} knots; allowed: a number, or 2 to 50 knots"
            )
        for k, value in enumerate(entries):
            label = f"{prefix}.{name}[{k}]" if isinstance(table, tuple) else f"{prefix}.{name}"
            _check_values(label, value, lambda a: (a >= 0) & (a <= 1), "a gain 0 <= g <= 1", sizes)
    require_one_batch_size(sizes)
    return params


def validate_ekf(params: EKFParams, prefix: str = "estimator") -> EKFParams:
    """Check an ``EKFParams``; return it unchanged (``ValueError`` naming the field)."""
    _check_kind(params, EKFParams, prefix)
    sizes = {}
    units = {"wheel_error": "", "sigma_xy": " cm", "sigma_theta": " rad"}
    for name, unit in units.items():
        allowed = f"0 < {name} <= 1e6{unit}"
        value = getattr(params, name)
        _check_values(f"{prefix}.{name}", value, lambda a: (a > 0) & (a <= 1e6), allowed, sizes)
    require_one_batch_size(sizes)
    return params


class ObserverState(NamedTuple):
    """The observer's estimate (a ``motion.SplitPose``)."""

    pose: motion.SplitPose


def _table(values: Any, r: jax.Array) -> jax.Array:
    """A gain (or table, piecewise linear over ``observer_radii``) at distance ``r``."""
    if not isinstance(values, tuple):
        return values + jnp.zeros_like(r)
    return table_at((values[0] + jnp.zeros_like(r), *values[1:]), r, observer_radii(len(values)))


def _observer_start(measured: motion.SplitPose, params: Any, robot: Robot) -> ObserverState:
    del params, robot
    return ObserverState(measured)


def _observer_update(state, predicted, command, measured, ref, params, robot, dt):
    """Blend the prediction toward ``measured`` by the gains at its distance to ``ref``."""
    del state, command, robot, dt
    # A plain square root: the complex absolute value's overflow guard is slow.
    d = jax.lax.complex(ref[0], ref[1]) - predicted.position
    distance = jnp.sqrt(d.real * d.real + d.imag * d.imag)
    g_position = _table(params.position, distance)
    g_heading = _table(params.heading, distance)
    # So that a gain of 1 returns the measurement bit for bit.
    position = measured.position + (1.0 - g_position) * (predicted.position - measured.position)
    back = (1.0 - g_heading) * measured.residual(predicted)
    return ObserverState(motion.SplitPose(position, measured.turned(-back), measured.theta - back))


class EKFState(NamedTuple):
    """The filter's estimate and covariance over ``[x cm, y cm, θ rad]``.

    ``covariance``: its six distinct entries ``(P₀₀, P₀₁, P₀₂, P₁₁, P₁₂, P₂₂)``.
    """

    pose: motion.SplitPose
    covariance: jax.Array


def _ekf_start(measured: motion.SplitPose, params: EKFParams, robot: Robot) -> EKFState:
    del robot
    zero = jnp.zeros_like(measured.theta)
    rxy, rth = params.sigma_xy**2 + zero, params.sigma_theta**2 + zero
    return EKFState(measured, jnp.stack((rxy, zero, zero, rxy, zero, rth)))


def _ekf_update(state, predicted, command, measured, ref, params, robot, dt) -> EKFState:
    """Predict the covariance over the period, then the Kalman correction toward ``measured``.

    With ``S = M + R``, ``P = M − M S⁻¹ M = R S⁻¹ M`` and ``K = P R⁻¹``: the
    six entries of ``R S⁻¹ M`` are written out elementwise, faster under
    ``vmap`` on XLA:CPU than 3 × 3 matrix products.
    """
    del ref
    v, omega = command.real, command.imag
    moved = predicted.position - state.pose.position
    # The arc's Jacobian in the pose: the heading turns the displacement,
    # F = [[1, 0, a], [0, 1, b], [0, 0, 1]].
    a, b = -moved.imag, moved.real
    p00, p01, p02, p11, p12, p22 = (state.covariance[i] for i in range(6))
    # Each wheel's travel has a relative error of std wheel_error; their sum
    # moves the centre, their difference over 2L turns it (independent wheels).
    travel_left = jnp.abs(v - robot.half_track * omega) * dt
    travel_right = jnp.abs(v + robot.half_track * omega) * dt
    q = params.wheel_error**2 * (travel_left**2 + travel_right**2) / 4.0
    # M = F P Fᵀ + Q.
    m02, m12, m22 = p02 + a * p22, p12 + b * p22, p22 + q / robot.half_track**2
    m00 = p00 + 2.0 * a * p02 + a * a * p22 + q
    m01 = p01 + a * p12 + b * p02 + a * b * p22
    m11 = p11 + 2.0 * b * p12 + b * b * p22 + q
    # S = M + R and its adjugate C (symmetric): S⁻¹ = C / det S.
    rxy, rth = params.sigma_xy**2, params.sigma_theta**2
    s00, s11, s22 = m00 + rxy, m11 + rxy, m22 + rth
    c00, c01, c02 = s11 * s22 - m12 * m12, m02 * m12 - m01 * s22, m01 * m12 - m02 * s11
    c11, c12, c22 = s00 * s22 - m02 * m02, m01 * m02 - s00 * m12, s00 * s11 - m01 * m01
    det = s00 * c00 + m01 * c01 + m02 * c02
    # P = R C M / det S: its six distinct entries.
    covariance = (
        jnp.stack(
            (
                rxy * (c00 * m00 + c01 * m01 + c02 * m02),
                rxy * (c00 * m01 + c01 * m11 + c02 * m12),
                rxy * (c00 * m02 + c01 * m12 + c02 * m22),
                rxy * (c01 * m01 + c11 * m11 + c12 * m12),
                rxy * (c01 * m02 + c11 * m12 + c12 * m22),
                rth * (c02 * m02 + c12 * m12 + c22 * m22),
            )
        )
        / det
    )
    p00, p01, p02, p11, p12, p22 = (covariance[i] for i in range(6))
    # The correction K y = P R⁻¹ y.
    residual = measured.position - predicted.position
    y0, y1, y2 = residual.real / rxy, residual.imag / rxy, measured.residual(predicted) / rth
    dx = p00 * y0 + p01 * y1 + p02 * y2
    dy = p01 * y0 + p11 * y1 + p12 * y2
    dth = p02 * y0 + p12 * y1 + p22 * y2
    cos_d, sin_d = sin_cos(dth)
    pose = motion.SplitPose(
        predicted.position + jax.lax.complex(dx, dy),
        predicted.heading * jax.lax.complex(cos_d, sin_d),
        predicted.theta + dth,
    )
    return EKFState(pose, covariance)


@dataclasses.dataclass(frozen=True, repr=False)
class Estimator(Pluggable):
    """A pose estimator as a value (hashable: a static ``jit`` argument).

    Attributes:
        name: short name for the CLI and tables (``"observer"``, ``"ekf"``).
        params_type: the class of its parameter pytree, with a static bool
            field ``compensate`` (its defaults the default parameters).
        validate: checks a parameter pytree before tracing; returns it.
        start: ``(measured SplitPose, params, robot) -> state``: a pytree
            whose ``pose`` field is the estimate, a ``SplitPose``.
        update: ``(state, predicted SplitPose, applied command v + iω,
            measured Measurement, ref (3,), params, robot, dt) -> state`` of
            the same structure: the correction of the loop's prediction.
    """

    KIND = "estimator"
    name: str
    params_type: type
    validate: Callable[[Any], Any]
    start: Callable[..., Any]
    update: Callable[..., Any]

    def __post_init__(self) -> None:
        # Checked here: an estimator is usable without registering.
        check_registry_name("estimator", self.name)
        for field in ("validate", "start", "update"):
            value = getattr(self, field)
            if not callable(value):
                raise ValueError(
                    f"estimator {self.name!r}: estimator.{field} = {described(value):.60} is not "
                    f"allowed; allowed: a function (docs/custom_controller.md)"
                )
        self.check_params_type()

    @property
    def own(self) -> bool:
        """Whether it is the package's own (which the tuners, the C export and the oracle know)."""
        return BUILT_IN.get(self.name) == self


OBSERVER = Estimator(
    "observer", ObserverParams, validate_observer, _observer_start, _observer_update
)
EKF = Estimator("ekf", EKFParams, validate_ekf, _ekf_start, _ekf_update)
BUILT_IN = {e.name: e for e in (OBSERVER, EKF)}
# Every estimator known by name: the built-in ones, then register_estimator's.
ESTIMATORS = dict(BUILT_IN)


def register_estimator(estimator: Estimator, *, replace: bool = False) -> Estimator:
    """Make ``estimator`` known by name and by its parameters' class; return it.

    Args:
        estimator: the estimator; its name lower-case letters, digits, ``-``
            and ``_`` (a CLI word), its parameter class its own.
        replace: allow a name already registered to another estimator (not a
            built-in one).
    """
    if not isinstance(estimator, Estimator):
        raise ValueError(
            f"estimator is a {type(estimator).__name__}; allowed: a wmr_jax.studies.Estimator"
        )
    replace = check_bool("replace", replace)
    name = estimator.name
    if name in ("none", "raw"):
        raise ValueError(
            f"estimator.name = {name!r} is not allowed: it means raw feedback; allowed: another"
        )
    known = ESTIMATORS.get(name)
    if known is not None and known != estimator and (not replace or name in BUILT_IN):
        raise ValueError(
            f"estimator.name = {name!r} is registered already; allowed: another name"
            + ("" if name in BUILT_IN else ", or replace=True")
        )
    owner = next(
        (e.name for e in ESTIMATORS.values() if e.params_type is estimator.params_type), name
    )
    if owner != name:
        raise ValueError(
            f"estimator {name!r}: estimator.params_type = {estimator.params_type.__name__} is "
            f"the parameter class of {owner!r}; allowed: a class of its own (parameters name "
            "their estimator)"
        )
    _custom_params(estimator, estimator.default_params())
    ESTIMATORS[name] = estimator
    return estimator


def resolve_estimator(value: Any) -> tuple[Estimator | None, Any]:
    """Return ``(Estimator, checked params)`` of ``None``, a name, an ``Estimator`` or params."""
    if value is None:
        return None, None
    if isinstance(value, str) and value in ESTIMATORS:
        value = ESTIMATORS[value]
    known = ESTIMATORS.values()
    estimator = value if isinstance(value, Estimator) else None
    estimator = estimator or next((e for e in known if type(value) is e.params_type), None)
    estimator = estimator or next((e for e in known if isinstance(value, e.params_type)), None)
    if estimator is None:
        classes = ", ".join(e.params_type.__name__ for e in ESTIMATORS.values())
        raise ValueError(
            f"estimator = {value!r:.80} is not allowed; allowed: None (raw feedback), "
            f"{' or '.join(repr(n) for n in ESTIMATORS)}, an Estimator, or parameters of one "
            f"of {classes} (an estimator of one's own: wmr_jax.studies.register_estimator)"
        )
    params = estimator.default_params() if value is estimator else value
    if estimator.own:
        return estimator, estimator.validate(params)
    return estimator, _custom_params(estimator, params)


def _custom_params(estimator: Estimator, params: Any) -> Any:
    """Check an estimator of one's own and its parameters before any run; return them.

    Its parameters: a pytree of numbers (each a scalar, or one per run; a list
    is such an array) with a static bool ``compensate``, which its
    ``validate`` returns. Its ``start`` and ``update`` are traced abstractly
    (``jax.eval_shape``), once per parameter structure and dtype.
    """
    shown = f"estimator {estimator.name!r}"
    require_pytree(shown, params)
    compensate = getattr(params, "compensate", None)
    leaves, structure = jax.tree_util.tree_flatten_with_path(
        params, is_leaf=lambda v: isinstance(v, list)
    )
    if not isinstance(compensate, bool) or any(
        getattr(path[-1], "name", None) == "compensate" for path, _ in leaves
    ):
        what = "no field compensate" if compensate is None else f"compensate = {compensate!r}"
        raise ValueError(
            f"{shown}: its parameters {type(params).__name__} have {what}; allowed: a bool "
            "field of a registered dataclass, marked static "
            '(dataclasses.field(default=True, metadata={"static": True}))'
        )
    numbers = []
    for path, leaf in leaves:
        if not is_traced(leaf):
            name = f"estimator{jax.tree_util.keystr(path)}"
            value = real_array(name, leaf, "a number, or one per run")
            if value.ndim > 1:
                raise ValueError(
                    f"{name} has shape {value.shape}; allowed: a number, or one per run"
                )
            leaf = value if isinstance(leaf, list) else leaf
        numbers.append(leaf)
    checked = estimator.validated(jax.tree.unflatten(structure, numbers))
    _check_state_once(estimator, jax.tree.structure(checked), np.dtype(float_dtype()).name)
    return checked


@functools.lru_cache(maxsize=64)
def _check_state_once(estimator: Estimator, structure: Any, dtype: str) -> None:
    """Trace ``start`` and ``update`` on abstract values; refuse a state the loop cannot carry."""
    real = jax.ShapeDtypeStruct((), dtype)
    turn = jax.ShapeDtypeStruct((), np.result_type(dtype, np.complex64))
    pose = motion.SplitPose(turn, turn, real)
    params = jax.tree.unflatten(structure, [real] * structure.num_leaves)
    robot = jax.tree.map(lambda _: real, Robot())
    ref = jax.ShapeDtypeStruct((3,), dtype)
    measured = Measurement(turn, turn, real, real)
    pose_kinds = jax.tree.map(_kind, pose)
    allowed = (
        "allowed: a state whose pose is the estimate, a SplitPose, of the same shapes and dtypes "
        "from start and update, e.g. a NamedTuple State(pose) (docs/custom_controller.md)"
    )
    name = f"estimator {estimator.name!r}"
    signature = f"allowed: {_START} -> state, {_UPDATE} -> state (docs/custom_controller.md)"
    calls = (
        (_START, estimator.start, (pose, params, robot)),
        (_UPDATE, estimator.update, (pose, turn, measured, ref, params, robot, real)),
    )
    state = ()
    for call, function, args in calls:
        try:
            out = jax.eval_shape(function, *state, *args)
        except Exception as err:  # any error of the estimator, reported in one line
            raise call_error(f"{name}: {call}", function, err, signature) from None
        got = getattr(out, "pose", None)
        if isinstance(out, motion.SplitPose) or got is None:
            what = "a bare SplitPose" if isinstance(out, motion.SplitPose) else type(out).__name__
            raise ValueError(f"{name}: {call} returned {what}, without a .pose; {allowed}")
        if not isinstance(got, motion.SplitPose) or jax.tree.map(_kind, got) != pose_kinds:
            raise ValueError(
                f"{name}: {call} returned a state whose pose is {_shown_kinds(got)}; {allowed}"
            )
        if state:
            before, after = (jax.tree_util.tree_flatten_with_path(x)[0] for x in (state[0], out))
            if jax.tree.structure(out) != jax.tree.structure(state[0]):
                raise ValueError(
                    f"{name}: {call} returned a state of another structure than start's; {allowed}"
                )
            for (path, a), (_, b) in zip(before, after, strict=True):
                if _kind(a) != _kind(b):
                    why = (
                        f" (the run computes in {dtype}: make the state from the inputs, e.g. "
                        "jnp.zeros_like(measured.theta))"
                        if a.shape == b.shape
                        else ""
                    )
                    raise ValueError(
                        f"{name}: {call} returned state{jax.tree_util.keystr(path)} of "
                        f"{_shown_kinds(b)} where start's is {_shown_kinds(a)}{why}; {allowed}"
                    )
        state = (out,)


_START = "start(measured, params, robot)"
_UPDATE = "update(state, predicted, command, measured, ref, params, robot, dt)"


def _kind(leaf: jax.ShapeDtypeStruct) -> tuple:
    return leaf.shape, leaf.dtype.name


def _shown_kinds(tree: Any) -> str:
    return ", ".join(f"shape {s} of {d}" for s, d in map(_kind, jax.tree.leaves(tree))) or "empty"
