"""An estimator of one's own, plugged into the one step (docs/custom_controller.md).

A fixed blend of prediction and measurement is the observer with constant
gains written another way: the runs must agree with the built-in observer's,
whichever way the blend is named, so that the step runs a user's estimator
exactly where it runs its own (update, compensation over the commands in
flight). The refusals come before any run, in one line naming the part.
"""

import dataclasses
import json
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.oracle.reference import reference_disturbed_rollout


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Blend:
    gain: Any = 0.3
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})


class BlendState(NamedTuple):
    pose: studies.SplitPose


def _start(measured, params, robot):
    return BlendState(measured)


def _update(state, predicted, command, measured, ref, params, robot, dt):
    p, m = predicted.stacked(), measured.pose().stacked()
    g = params.gain
    turn = measured.residual(predicted)
    pose = jnp.stack([p[0] + g * (m[0] - p[0]), p[1] + g * (m[1] - p[1]), p[2] + g * turn])
    return BlendState(studies.SplitPose.of(pose))


def _validate(params):
    gain = params.gain
    if not isinstance(gain, jax.core.Tracer) and not np.all((0 <= gain) & (np.asarray(gain) <= 1)):
        raise ValueError(f"estimator.gain = {gain!r} is not allowed; allowed: 0 to 1")
    return params


BLEND = studies.Estimator("blend", Blend, _validate, _start, _update)
REFS = np.array([[40.0, 20.0, 0.0], [-30.0, 25.0, 1.0], [10.0, -35.0, -2.5]])
GAINS = w.Gains(kr=60.0, k_theta=10.0)


@pytest.fixture
def registry(estimator_registry):
    return estimator_registry


def _spec(delay: float, steps: int = 90):
    key = jax.random.key(3)
    spec = studies.sample_disturbance(key, REFS, steps, noise_xy=0.5, noise_theta=0.02)
    return spec._replace(delay=np.full(len(REFS), delay))


@pytest.mark.parametrize(("delay", "compensate"), [(0, True), (2, True), (2, False)])
def test_a_blend_of_ones_own_runs_as_the_observer_with_constant_gains(registry, delay, compensate):
    spec = _spec(delay)
    observer = studies.ObserverParams(position=0.3, heading=0.3, compensate=compensate)
    want = studies.disturbed_rollout(spec, GAINS, estimator=observer)
    studies.register_estimator(BLEND)
    for given in (Blend(compensate=compensate), "blend", BLEND):
        if given in ("blend", BLEND) and not compensate:
            continue  # by name or value: the default parameters, which compensate
        got = studies.disturbed_rollout(spec, GAINS, estimator=given)
        for field in ("poses", "estimates", "v", "omega"):
            np.testing.assert_allclose(got[field], want[field], rtol=0, atol=1e-9, err_msg=field)
    # The runs are the estimator's: another gain moves them.
    other = studies.disturbed_rollout(spec, GAINS, estimator=Blend(gain=0.05))
    assert np.max(np.abs(other["estimates"] - want["estimates"])) > 0.01


def test_an_unregistered_estimator_runs_by_value_and_the_studies_name_it(registry):
    spec = _spec(1)
    m = studies.disturbed_metrics(spec, GAINS, estimator=BLEND)
    assert np.all(np.isfinite(m.final_distance))
    # Its parameters mean nothing to the package until it is registered.
    with pytest.raises(ValueError, match=r"estimator = Blend\(gain=0.3.*allowed: None"):
        studies.disturbed_metrics(spec, GAINS, estimator=Blend())
    studies.register_estimator(BLEND)
    loop = studies.ClosedLoop("shim-sung", GAINS, Blend(gain=0.2))
    row = studies.evaluate_loop(loop, REFS[:2], condition="both")
    assert row["feedback"] == "blend"
    rows = studies.monte_carlo(
        jax.random.key(0), params=GAINS, n_runs=4, noise_xy=(0.5,), noise_deg=(1.0,),
        estimator="blend", horizon=3.0,
    )  # fmt: skip
    assert [r["feedback"] for r in rows] == ["blend"]


def _with(**fields):
    return dataclasses.replace(BLEND, **fields)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class LeafCompensate:
    gain: Any = 0.3
    compensate: Any = True  # a leaf: jit would trace it


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NoCompensate:
    gain: Any = 0.3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NoDefault:
    gain: Any
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})


@dataclasses.dataclass(frozen=True)
class NotATree:
    gain: Any = 0.3
    compensate: bool = True


class Grown(NamedTuple):
    pose: Any
    count: Any


def _python_if(state, predicted, command, measured, ref, params, robot, dt):
    if params.gain > 0.5:  # a Python if on a traced value: line _IF_LINE
        return state
    return BlendState(predicted)


_IF_LINE = _python_if.__code__.co_firstlineno + 1


def _raises(state, predicted, command, measured, ref, params, robot, dt):
    return BlendState(measured.nope)


_RAISES_LINE = _raises.__code__.co_firstlineno + 1
_ALLOWED = (
    "allowed: a state whose pose is the estimate, a SplitPose, of the same shapes and dtypes "
    "from start and update, e.g. a NamedTuple State(pose) (docs/custom_controller.md)"
)
_START = "start(measured, params, robot)"
_UPDATE = "update(state, predicted, command, measured, ref, params, robot, dt)"
_STATIC = (
    "allowed: a bool field of a registered dataclass, marked static (dataclasses.field("
    'default=True, metadata={"static": True}))'
)


@pytest.mark.parametrize(
    ("estimator", "message"),
    [
        (
            _with(params_type=LeafCompensate),
            f"its parameters LeafCompensate have compensate = True; {_STATIC}",
        ),
        (
            _with(params_type=NoCompensate),
            f"its parameters NoCompensate have no field compensate; {_STATIC}",
        ),
        (
            _with(params_type=NotATree),
            "its parameters NotATree are not a pytree; allowed: a dataclass registered with "
            "jax.tree_util.register_dataclass (docs/custom_controller.md)",
        ),
        (
            _with(params_type=NoDefault),
            "estimator.params_type() raised TypeError: NoDefault.__init__() missing 1 required "
            "positional argument: 'gain'; allowed: a class whose every field has a default (the "
            "default parameters)",
        ),
        (
            _with(validate=lambda params: params.gain),
            "estimator.validate(params) returned 0.3; allowed: the parameters it checked "
            "(validate(params) -> params)",
        ),
        (
            _with(start=lambda measured, params, robot: measured),
            f"{_START} returned a bare SplitPose, without a .pose; {_ALLOWED}",
        ),
        (
            _with(start=lambda measured, params, robot: {"pose": measured}),
            f"{_START} returned dict, without a .pose; {_ALLOWED}",
        ),
        (
            _with(update=lambda s, p, c, m, r, g, robot, dt: Grown(p, 0.0)),
            f"{_UPDATE} returned a state of another structure than start's; {_ALLOWED}",
        ),
        (
            _with(update=lambda s, p, c, m, r, g, robot, dt: BlendState(p.stacked())),
            f"{_UPDATE} returned a state whose pose is shape (3,) of float64; {_ALLOWED}",
        ),
        (
            _with(
                start=lambda measured, params, robot: Grown(measured, jnp.zeros(1)),
                update=lambda s, p, c, m, r, g, robot, dt: Grown(p, jnp.zeros(2)),
            ),
            f"{_UPDATE} returned state.count of shape (2,) of float64 where start's is shape "
            f"(1,) of float64; {_ALLOWED}",
        ),
        (
            _with(
                start=lambda measured, params, robot: Grown(measured, jnp.zeros(1)),
                update=lambda s, p, c, m, r, g, robot, dt: Grown(p, jnp.zeros(1, jnp.int32)),
            ),
            f"{_UPDATE} returned state.count of shape (1,) of int32 where start's is shape "
            "(1,) of float64 (the run computes in float64: make the state from the inputs, e.g. "
            f"jnp.zeros_like(measured.theta)); {_ALLOWED}",
        ),
        (
            _with(
                update=lambda s, p, c, m, r, g, robot, dt: BlendState(
                    studies.SplitPose(p.position[None], p.heading[None], p.theta[None])
                )
            ),
            f"{_UPDATE} returned a state whose pose is shape (1,) of complex128, shape (1,) of "
            f"complex128, shape (1,) of float64; {_ALLOWED}",
        ),
        (
            _with(update=_raises),
            f"{_UPDATE} raised AttributeError at test_custom_estimator.py:{_RAISES_LINE}: "
            f"'Measurement' object has no attribute 'nope'; allowed: {_START} -> state, "
            f"{_UPDATE} -> state (docs/custom_controller.md)",
        ),
        (
            # No line of the estimator's file was reached: the call itself failed.
            _with(update=lambda state, predicted, command, measured: state),
            f"{_UPDATE} raised TypeError: <lambda>() takes 4 positional arguments but 8 were "
            f"given; allowed: {_START} -> state, {_UPDATE} -> state (docs/custom_controller.md)",
        ),
        (
            _with(update=_python_if),
            f"{_UPDATE} raised TracerBoolConversionError at test_custom_estimator.py:{_IF_LINE}: "
            "it asks the value of a traced array (a Python if, bool(), float() or int() of one); "
            "allowed: jnp.where or jax.lax.cond, as it is traced by jit, vmap and grad "
            "(docs/custom_controller.md)",
        ),
    ],
    ids=[
        "leaf-compensate", "no-compensate", "no-pytree", "no-default", "validate-none",
        "bare-pose", "dict", "structure", "pose-shape", "state-shape", "state-dtype",
        "pose-fields", "raises", "no-call", "python-if",
    ],
)  # fmt: skip
def test_an_estimator_the_loop_cannot_carry_is_refused_when_registered_and_run(
    registry, estimator, message
):
    def refused(run):
        with jax.enable_x64(True), pytest.raises(ValueError) as info:
            run()
        assert str(info.value) == f"estimator 'blend': {message}"

    refused(lambda: studies.register_estimator(estimator))
    assert "blend" not in registry
    refused(lambda: studies.disturbed_metrics(_spec(1), GAINS, estimator=estimator))


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (
            Blend(gain=True),
            "estimator.gain = True is not allowed; allowed: a number, or one per run",
        ),
        (Blend(gain="a"), "estimator.gain = 'a' is not allowed; allowed: a number, or one per run"),
        (
            Blend(gain=np.ones((3, 2))),
            "estimator.gain has shape (3, 2); allowed: a number, or one per run",
        ),
    ],
)
def test_parameters_that_are_not_numbers_are_named_by_field(registry, params, message):
    studies.register_estimator(BLEND)
    with pytest.raises(ValueError) as info:
        studies.disturbed_metrics(_spec(1), GAINS, estimator=params)
    assert str(info.value) == message


def test_a_list_of_parameters_is_one_per_run_as_an_array_is(registry):
    studies.register_estimator(BLEND)
    spec = _spec(1)
    as_list = studies.disturbed_rollout(spec, GAINS, estimator=Blend(gain=[0.1, 0.3, 0.9]))
    as_array = studies.disturbed_rollout(
        spec, GAINS, estimator=Blend(gain=np.array([0.1, 0.3, 0.9]))
    )
    one = studies.disturbed_rollout(spec, GAINS, estimator=Blend(gain=0.9))
    np.testing.assert_array_equal(as_list["estimates"], as_array["estimates"])
    np.testing.assert_array_equal(as_list["estimates"][2], one["estimates"][2])


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Table:
    knots: Any = (0.05, 0.3)  # a tuple: a table of numbers, each a leaf
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class BlendOfTable(Blend):
    pass


def test_parameters_resolve_to_their_own_estimator_and_a_subclass_to_its_parent(registry):
    table = studies.register_estimator(
        _with(
            name="table",
            params_type=Table,
            validate=lambda params: params,
            update=lambda s, p, c, m, r, g, robot, dt: _update(
                s, p, c, m, r, Blend(g.knots[1]), robot, dt
            ),
        )
    )
    studies.register_estimator(BLEND)
    spec = _spec(1)
    by_table = studies.disturbed_rollout(spec, GAINS, estimator=Table())
    np.testing.assert_array_equal(
        by_table["estimates"], studies.disturbed_rollout(spec, GAINS, estimator=table)["estimates"]
    )
    np.testing.assert_array_equal(
        by_table["estimates"],
        studies.disturbed_rollout(spec, GAINS, estimator="blend")["estimates"],
    )  # the table's second knot is the blend's default gain, 0.3
    # A subclass of a registered class runs as its parent's estimator.
    sub = studies.disturbed_rollout(spec, GAINS, estimator=BlendOfTable(gain=0.05))
    own = studies.disturbed_rollout(spec, GAINS, estimator=Blend(gain=0.05))
    np.testing.assert_array_equal(sub["estimates"], own["estimates"])

    # A registered subclass of EKFParams is its own estimator's, not the EKF's.
    @jax.tree_util.register_dataclass
    @dataclasses.dataclass(frozen=True)
    class UKFParams(studies.EKFParams):
        pass

    ukf = studies.register_estimator(
        _with(
            name="ukf",
            params_type=UKFParams,
            validate=lambda params: params,
            update=lambda s, p, c, m, r, g, robot, dt: BlendState(p),  # odometry alone
        )
    )
    row = studies.evaluate_loop(studies.ClosedLoop("shim-sung", GAINS, UKFParams()), REFS[:1])
    assert row["feedback"] == ukf.name
    with pytest.raises(ValueError) as info:
        studies.disturbed_metrics(spec, GAINS, estimator=3.0)
    assert str(info.value) == (
        "estimator = 3.0 is not allowed; allowed: None (raw feedback), 'observer' or 'ekf' or "
        "'table' or 'blend' or 'ukf', an Estimator, or parameters of one of ObserverParams, "
        "EKFParams, Table, Blend, UKFParams (an estimator of one's own: "
        "wmr_jax.studies.register_estimator)"
    )
    with pytest.raises(ValueError, match="replace = 'yes' is not allowed"):
        studies.register_estimator(BLEND, replace="yes")
    with pytest.raises(ValueError) as info:
        _with(params_type=Blend())
    assert str(info.value) == (
        "estimator 'blend': estimator.params_type = Blend(gain=0.3, compensate=True) is not "
        "allowed; allowed: a class (its defaults are the default parameters)"
    )


def test_another_estimators_parameter_class_is_refused(registry):
    with pytest.raises(ValueError) as info:
        studies.register_estimator(_with(name="ukf", params_type=studies.EKFParams))
    assert str(info.value) == (
        "estimator 'ukf': estimator.params_type = EKFParams is the parameter class of 'ekf'; "
        "allowed: a class of its own (parameters name their estimator)"
    )
    assert studies.disturbed_metrics(_spec(1), GAINS, estimator=studies.EKFParams()) is not None


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        (
            {"name": "My Filter"},
            "estimator.name = 'My Filter' is not allowed; allowed: lower-case letters, digits, "
            "'-' and '_', starting with a letter or digit",
        ),
        ({"update": 3}, "estimator 'blend': estimator.update = 3 is not allowed"),
        ({"params_type": Blend()}, "estimator 'blend': estimator.params_type = .* is not allowed"),
    ],
)
def test_an_estimator_with_a_bad_field_is_refused_when_built(fields, message):
    with pytest.raises(ValueError, match=message):
        _with(**fields)


def test_names_are_kept_and_the_built_in_ones_are_not_replaced(registry):
    assert studies.register_estimator(BLEND) is BLEND
    studies.register_estimator(BLEND)  # the same again: nothing to refuse
    other = _with(start=lambda measured, params, robot: BlendState(measured))
    with pytest.raises(
        ValueError, match="'blend' is registered already; allowed: another name, or replace=True"
    ):
        studies.register_estimator(other)
    assert studies.register_estimator(other, replace=True) is registry["blend"]
    with pytest.raises(ValueError, match="'ekf' is registered already; allowed: another name$"):
        studies.register_estimator(_with(name="ekf"), replace=True)
    with pytest.raises(
        ValueError, match="estimator is a str; allowed: a wmr_jax.studies.Estimator"
    ):
        studies.register_estimator("blend")
    for word in ("none", "raw"):  # what --estimator reads as raw feedback
        with pytest.raises(ValueError, match=f"'{word}' is not allowed: it means raw feedback"):
            studies.register_estimator(_with(name=word))


def test_the_tuner_the_export_and_the_reference_refuse_it_by_name(registry):
    studies.register_estimator(BLEND)
    with pytest.raises(
        ValueError, match="estimator = 'blend' is not allowed; allowed: None, 'observer', 'ekf'"
    ):
        w.tuning.RobustConfig(estimator="blend").validate()
    loop = studies.ClosedLoop("shim-sung", GAINS, "blend")
    with pytest.raises(ValueError, match="loop.estimator = <Estimator 'blend'> is not allowed"):
        w.export.c_sources(loop)
    with pytest.raises(ValueError, match="estimator = <Estimator 'blend'> is not allowed"):
        reference_disturbed_rollout(REFS[0], GAINS, noise=np.zeros((5, 3)), estimator="blend")


def test_a_registered_estimators_parameters_are_saved_and_loaded_with_the_gains(registry, tmp_path):
    path = tmp_path / "tuned_gains.json"
    with pytest.raises(ValueError) as info:  # load_tuned could not read it back
        w.tuning.tuned_json(GAINS, BLEND)
    assert str(info.value) == (
        "estimator 'blend' is not registered; allowed: a registered estimator "
        "(wmr_jax.studies.register_estimator), which load_tuned can read back"
    )
    studies.register_estimator(BLEND)
    path.write_text(json.dumps(w.tuning.tuned_json(GAINS, Blend(gain=0.2, compensate=False))))
    loop = w.load_tuned(path)
    assert loop.estimator == Blend(gain=0.2, compensate=False) and loop.params == GAINS
    del registry["blend"]  # a session that has not registered it
    with pytest.raises(ValueError) as info:
        w.load_tuned(path)
    assert str(info.value) == (
        f"'{path}': estimator kind = 'blend' is not allowed; allowed: 'observer' or 'ekf', or "
        "one registered with wmr_jax.studies.register_estimator before loading"
    )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Moded:
    gain: Any = 0.3
    mode: str = dataclasses.field(default="fast", metadata={"static": True})
    compensate: bool = dataclasses.field(default=True, metadata={"static": True})


def test_a_static_field_beside_compensate_runs_but_is_not_saved(registry):
    moded = studies.register_estimator(_with(name="moded", params_type=Moded))
    assert np.all(
        np.isfinite(studies.disturbed_metrics(_spec(1), GAINS, estimator=moded).final_distance)
    )
    with pytest.raises(ValueError) as info:
        w.tuning.tuned_json(GAINS, Moded())
    assert str(info.value) == (
        "estimator 'moded': its static field 'mode' cannot be written to a tuned_gains.json; "
        "allowed: a dataclass of numbers and tuples of them, and compensate"
    )


def test_a_run_an_estimator_of_ones_own_sends_off_range_names_it(registry):
    def diverge(state, predicted, command, measured, ref, params, robot, dt):
        return BlendState(predicted._replace(position=predicted.position * jnp.nan))

    studies.register_estimator(_with(update=diverge))
    with pytest.raises(ValueError) as info:
        studies.disturbed_metrics(_spec(1), GAINS, estimator="blend")
    assert str(info.value).endswith(
        "allowed: disturbances, gains and dt that keep the sampled law stable (docs/model.md "
        "§4, §7), and estimates of 'blend' that stay finite"
    ), str(info.value)


def test_the_robust_tuner_refuses_a_registered_estimator_by_its_flag(registry):
    from types import SimpleNamespace

    from wmr_jax._src.cli.tune_robust import config_from

    studies.register_estimator(BLEND)
    with pytest.raises(ValueError) as info:
        config_from(SimpleNamespace(estimator="blend"))
    assert str(info.value) == (
        "--estimator 'blend' is not allowed with --robust; allowed: none, ekf or observer, the "
        "estimators the tuner knows"
    )


def test_the_command_line_runs_a_registered_estimator_and_says_how_to_register_one(
    registry, tmp_path, capsys
):
    from wmr_jax.cli import main

    argv = ["robustness", "--out", str(tmp_path), "--runs", "4", "--controller", "shim-sung"]
    assert main([*argv, "--estimator", "blend"]) == 2
    said = capsys.readouterr().err.strip()
    assert said.endswith(
        "--estimator 'blend' is not allowed; allowed: none, observer, ekf (one's own: "
        "registered by wmr_jax.studies.register_estimator in a script that then calls "
        "wmr_jax.cli.main)"
    )
    studies.register_estimator(BLEND)
    assert main([*argv, "--estimator", "blend"]) == 0
    assert "| condition | controller | feedback |" in capsys.readouterr().out
    rows = json.loads((tmp_path / "robustness.json").read_text())["rows"]
    assert {row["feedback"] for row in rows} == {"blend"}
    assert "estimator blend, seed 0" in (tmp_path / "robustness.md").read_text()
