"""What a user meets first: far-off goals, own controllers, the package's surface, --version."""

import dataclasses
import functools
import importlib.metadata
import inspect
import pydoc
import re
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import controllers
from wmr_jax._src.cli.main import main
from wmr_jax._src.model.controllers import base

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- baselines far from the origin


def _run(controller, x64, offset):
    with jax.enable_x64(x64):
        ref, init = [offset + 10.0, 0.0, np.pi / 2], [offset, 0.0, 0.0]
        traj = w.rollout(ref, controller=controller, init=init, steps=606)
        assert traj.poses.dtype == (np.float64 if x64 else np.float32)
        # final_poses runs in the same frame as rollout.
        final = w.final_poses(np.array([ref]), controller=controller, init=init, steps=200)
        np.testing.assert_allclose(final[0], traj.poses[200], rtol=0, atol=1e-6 * offset + 1e-9)
        poses = np.asarray(traj.poses, np.float64) - [offset, 0.0, 0.0]
        return float(w.arrival_time(traj, ref, dt=w.DEFAULT_DT)), poses


@pytest.mark.parametrize("controller", ["aicardi", "astolfi-corke"])
@pytest.mark.parametrize("offset", [1e4, 1e6])
def test_polar_baselines_arrive_alike_in_float32_and_float64_far_from_the_origin(
    controller, offset
):
    """Near 1e4 cm float32 spaces positions 1e-3 cm apart: aicardi used to end 90° off."""
    t32, poses32 = _run(controller, False, offset)
    t64, poses64 = _run(controller, True, offset)
    t0, poses0 = _run(controller, True, 0.0)
    assert np.isfinite(t32) and abs(t32 - t64) <= w.DEFAULT_DT * 1.001, (t32, t64)
    # Run in the reference's frame, it is the run near the origin, moved: to
    # the rounding of the dtype (positions to the float32 spacing at offset).
    assert t64 == t0
    np.testing.assert_allclose(poses64, poses0, rtol=0, atol=1e-7)
    spacing = float(np.spacing(np.float32(offset)))
    np.testing.assert_allclose(poses32[:, :2], poses0[:, :2], rtol=0, atol=spacing)
    np.testing.assert_allclose(poses32[:, 2], poses0[:, 2], rtol=0, atol=1e-5)


@pytest.mark.parametrize("law", ["aicardi_control", "astolfi_control"])
def test_polar_goal_floor_is_1e_3_cm_at_ordinary_coordinates(law):
    """Within 1e-3 cm the laws only turn, beyond it they drive (docs/model.md §3.8), any dtype."""
    control = getattr(controllers, law)
    params = (
        w.controllers.AicardiGains() if law == "aicardi_control" else w.controllers.AstolfiGains()
    )
    for x64 in (False, True):
        with jax.enable_x64(x64):
            for origin in (0.0, 100.0):
                pose = np.array([origin, -origin, 0.0])
                for step, drives in ((2e-3, True), (5e-4, False)):
                    ref = pose + np.array([step, 0.0, np.pi / 2])
                    v, omega = control(pose, ref, params)
                    assert (float(v) != 0.0) == drives, (x64, origin, step, float(v))
                    assert float(omega) != 0.0
            # Far off, float32 resolves no better than its spacing of positions;
            # float64 keeps the fixed floor.
            pose = np.array([1e4, 0.0, 0.0])
            v, _ = control(pose, pose + np.array([0.01, 0.0, np.pi / 2]), params)
            assert (float(v) != 0.0) == x64


# ---------------------------------------------------------------- custom controllers


def _mine(pose, ref, params, *, temperature=None, frame=None):
    err = w.controllers.polar_error(pose, ref, frame=frame)
    return 3.0 * err.r * err.cos_phi, 4.0 * err.sin_phi


def test_a_command_without_the_frame_keyword_is_refused_in_one_line():
    """Not a TypeError from inside the traced loop: a ValueError when the Controller is built."""

    def no_frame(pose, ref, params, *, temperature=None):
        return _mine(pose, ref, params)

    with pytest.raises(ValueError) as info:
        w.Controller(name="no-frame", command=no_frame, params_type=w.Gains, validate=lambda g: g)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("controller 'no-frame': controller.command = ")
    assert "unexpected keyword argument 'frame'" in message
    assert "allowed: a function command(pose, ref, params, *, temperature=None, frame=None)" in (
        message
    )

    def positional_only(pose, ref, params):
        return _mine(pose, ref, params)

    with pytest.raises(ValueError, match="unexpected keyword argument 'temperature'"):
        w.Controller(name="p", command=positional_only, params_type=w.Gains, validate=lambda g: g)
    with pytest.raises(ValueError, match=r"controller 'r': controller.region = .*allowed: a "):
        w.Controller(
            name="r",
            command=_mine,
            params_type=w.Gains,
            validate=lambda g: g,
            region=lambda pose, ref, params: 0,
        )
    with pytest.raises(ValueError, match=r"controller.validate = .*too many positional"):
        w.Controller(name="v", command=_mine, params_type=w.Gains, validate=lambda: None)
    # Keywords with defaults, or **kwargs, are what the loops need; both run.
    for command in (_mine, lambda pose, ref, params, **kw: _mine(pose, ref, params, **kw)):
        custom = w.Controller(name="ok", command=command, params_type=w.Gains, validate=lambda g: g)
        final = np.asarray(w.rollout([20.0, 5.0, 0.0], controller=custom, steps=150).poses[-1])
        assert np.hypot(final[0] - 20.0, final[1] - 5.0) < 0.1


@pytest.mark.parametrize(
    ("returned", "message"),
    [
        (lambda err, pose: (3.0 * err.r[..., None], 0.0 * err.r), "returned v of shape (1,)"),
        (lambda err, pose: (pose, pose), "returned v of shape (3,)"),
        (lambda err, pose: (err.r, err.r, err.r), "returned 3 values"),
        (lambda err, pose: err.r, "returned one array of shape () of float"),
        (lambda err, pose: (err.r, err.sin_phi > 0), "returned omega of shape () of bool"),
        (lambda err, pose: (err.r, err.missing), "'PolarError' object has no attribute 'missing'"),
    ],
    ids=["column", "poses", "three", "one", "bool", "raises"],
)
def test_a_command_that_returns_no_pair_of_scalars_is_refused_before_the_loop(returned, message):
    """Not JAX's error from inside the traced scan: one line naming the controller."""

    def command(pose, ref, params, *, temperature=None, frame=None):
        return returned(w.controllers.polar_error(pose, ref, frame=frame), pose)

    odd = w.Controller(name="odd", command=command, params_type=w.Gains, validate=lambda g: g)
    for run in (
        lambda: w.rollout([20.0, 5.0, 0.0], controller=odd, steps=5),
        lambda: w.batch_rollout([[20.0, 5.0, 0.0]] * 2, w.Gains(kr=[60.0, 70.0]), controller=odd),
    ):
        with pytest.raises(ValueError) as info:
            run()
        text = str(info.value)
        assert text.startswith("controller 'odd': controller.command(pose (3,), ref (3,), params)")
        assert message in text and "\n" not in text
        assert text.endswith(
            "allowed: (v, omega), two real scalars for one pose (3,) (docs/custom_controller.md)"
        )


def test_custom_controller_page_runs_as_written(tmp_path, monkeypatch, capsys, estimator_registry):
    """docs/custom_controller.md: its Python blocks run; they register "mine" and "blend"."""
    page = (ROOT / "docs" / "custom_controller.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    assert len(blocks) == 3
    # The page registers a controller and an estimator: keep them out of the
    # other tests' registries.
    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))
    monkeypatch.chdir(tmp_path)
    page_names = {"__name__": "page"}
    exec(compile(blocks[0], "docs/custom_controller.md", "exec"), page_names)
    assert "mine" in w.controllers.registered_names()
    # Its validate refuses what NumPy would read as a number.
    for bad in (True, "3"):
        with pytest.raises(ValueError, match=f"gains.k_rho = {bad!r} is not allowed"):
            w.rollout([40.0, 20.0, 0.0], page_names["MyGains"](k_rho=bad), controller="mine")
    out = capsys.readouterr().out
    assert "final pose" in out and "d(miss after 1 s)/d(k_rho)" in out
    arrival = float(re.search(r"arrived after (\S+) s", out).group(1))
    assert np.isfinite(arrival)
    # The second: a disturbance of one's own, a sensor whose x reads 5 cm too far.
    exec(compile(blocks[1], "docs/custom_controller.md", "exec"), {"__name__": "page"})
    end = re.search(r"biased sensor: \[\s*(\S+)\s+(\S+)\]", capsys.readouterr().out)
    assert abs(float(end[1]) - 35.0) < 1.0 and abs(float(end[2]) - 20.0) < 1.0
    # The third: an estimator of one's own, by name and by its parameters.
    exec(compile(blocks[2], "docs/custom_controller.md", "exec"), {"__name__": "page"})
    assert "blend" in estimator_registry
    out = capsys.readouterr().out
    finals = re.findall(r"^(.+): final distance \[(.*)\] cm$", out, flags=re.M)
    assert [label for label, _ in finals] == [
        "None",
        "blend",
        "BlendParams(gain=0.1, compensate=True)",
        "BlendParams(gain=[0.1, 0.5], compensate=True)",
    ]
    assert all(0 < float(d) < 2.0 for _, row in finals for d in row.split())


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class _K:
    k: float = 3.0


@dataclasses.dataclass(frozen=True)
class _Unregistered:
    k: float = 3.0


def _k_command(pose, ref, params, *, temperature=None, frame=None):
    err = w.controllers.polar_error(pose, ref, frame=frame)
    if err.r > 1.0:  # a Python if on a traced value: line _IF_LINE
        return params.k * err.r * err.cos_phi, 4.0 * err.sin_phi
    return 0.0 * err.r, 0.0 * err.r


_IF_LINE = _k_command.__code__.co_firstlineno + 2


def _nan_command(pose, ref, params, *, temperature=None, frame=None):
    err = w.controllers.polar_error(pose, ref, frame=frame)
    return jnp.log(err.r - 100.0), 4.0 * err.sin_phi  # NaN within 100 cm


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        (
            {"params_type": _Unregistered},
            "controller 'k': its parameters _Unregistered are not a pytree; allowed: a dataclass "
            "registered with jax.tree_util.register_dataclass (docs/custom_controller.md)",
        ),
        (
            {"validate": lambda params: params.k},
            "controller 'k': controller.validate(params) returned 3.0; allowed: the parameters "
            "it checked (validate(params) -> params)",
        ),
        (
            # A callable without code of its own: no file and line to name.
            {"command": functools.partial(_k_command)},
            "controller 'k': controller.command(pose (3,), ref (3,), params) raised "
            "TracerBoolConversionError: it asks the value of a traced array (a Python if, "
            "bool(), float() or int() of one); allowed: jnp.where or jax.lax.cond, as it is "
            "traced by jit, vmap and grad (docs/custom_controller.md)",
        ),
        (
            {"command": _k_command},
            "controller 'k': controller.command(pose (3,), ref (3,), params) raised "
            f"TracerBoolConversionError at test_usability.py:{_IF_LINE}: it asks the value of a "
            "traced array (a Python if, bool(), float() or int() of one); allowed: jnp.where or "
            "jax.lax.cond, as it is traced by jit, vmap and grad (docs/custom_controller.md)",
        ),
        (
            {"command": _nan_command},
            "the run left the range of float64 (a pose became inf or NaN); allowed: gains and dt "
            "that keep the sampled law stable (docs/model.md §4), and commands of 'k' that stay "
            "finite",
        ),
    ],
    ids=["unregistered", "validate-returns-a-gain", "partial", "python-if", "nan"],
)
def test_a_newcomers_slips_in_a_law_are_named_in_one_line(fields, message):
    """The usual first mistakes with a law of one's own, each said where it happened."""
    fields = {"command": _mine, "params_type": _K, "validate": lambda params: params, **fields}
    law = w.Controller(name="k", **fields)
    with jax.enable_x64(True), pytest.raises(ValueError) as info:
        w.rollout([20.0, 5.0, 0.0], controller=law, steps=5)
    assert str(info.value) == message


# ---------------------------------------------------------------- the package's surface


def test_a_plain_import_reaches_every_family_on_first_use():
    code = (
        "import sys, wmr_jax\n"
        "assert 'wmr_jax.cli' not in sys.modules and 'wmr_jax.report' not in sys.modules\n"
        "assert callable(wmr_jax.cli.main)\n"
        "assert 'cli' in dir(wmr_jax)\n"
        "for name in ('controllers', 'dynamics', 'tuning', 'studies', 'report', 'export'):\n"
        "    assert getattr(wmr_jax, name).__name__ == 'wmr_jax.' + name\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
    assert callable(w.cli.main)
    with pytest.raises(AttributeError, match="no attribute 'nonesuch'"):
        w.nonesuch  # noqa: B018


def test_all_lists_every_public_name_of_the_package():
    assert len(w.__all__) == len(set(w.__all__))
    for name in w.__all__:
        assert hasattr(w, name), name
    # Everything __init__.py re-exports (``import X as X``), and the families.
    source = (ROOT / "wmr_jax" / "__init__.py").read_text(encoding="utf-8")
    exported = re.findall(r"^from wmr_jax\S* import (\w+) as \1\b", source, flags=re.M)
    families = ["cli", "controllers", "dynamics", "export", "report", "studies", "tuning"]
    assert sorted(w.__all__) == sorted(exported + families)


# ---------------------------------------------------------------- help() on the entry points

_PARAMETERS = [
    "gains",
    "init",
    "dt",
    "steps",
    "robot",
    "velocity",
    "controller",
    "temperature",
    "substeps",
    "wheel_limit",
]


@pytest.mark.parametrize(
    "entry, first, summary",
    [
        ("rollout", "ref", "Drive the robot from ``init`` towards ``ref`` and record the whole"),
        ("batch_rollout", "refs", "Run ``rollout`` for a batch, in one call."),
        ("final_poses", "refs", "Return only the last pose of each run, ``(N, 3)``;"),
    ],
)
def test_help_shows_the_entry_points_signature_and_docstring(entry, first, summary):
    function = getattr(w, entry)
    signature = inspect.signature(function)
    assert list(signature.parameters) == [first, *_PARAMETERS]
    assert signature.parameters["steps"].kind is inspect.Parameter.KEYWORD_ONLY
    assert function.__doc__.startswith(summary)
    text = pydoc.render_doc(function, renderer=pydoc.plaintext)
    # The default controller reads as its name, not a dataclass of function addresses.
    assert "controller: 'Controller | str' = <Controller 'shim-sung'>" in text
    assert " at 0x" not in text and "{options}" not in text
    # The shared option lines continue the Args list, without a blank line.
    assert re.search(r"gains: [^\n]*\n(?:[^\n]+\n)*?\s+init: ", text), text


# ---------------------------------------------------------------- wmr-jax --version, bare wmr-jax


def test_version_prints_the_installed_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out == f"wmr-jax {importlib.metadata.version('wmr_jax')}\n"


def test_bare_command_prints_the_help_with_status_2(capsys):
    assert main([]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("usage: wmr-jax")
    assert "--version" in captured.err
    for command in ("simulate", "compare", "bench"):
        assert command in captured.err


def test_a_heading_in_degrees_is_warned_and_one_in_radians_is_not():
    """A whole number beyond 2π is most likely degrees; an unwrapped angle in radians is not."""
    with pytest.warns(
        w.HeadingUnitsWarning, match=r"ref has heading 90 rad, a whole number beyond"
    ):
        w.rollout([40.0, 20.0, 90.0], w.Gains(kr=60.0, k_theta=10.0), steps=3)
    refs = [[40.0, 0.0, 0.5], [9.0, 9.0, -135.0], [1.0, 1.0, 120.0]]  # the widest is named
    for given in (refs, jnp.array(refs)):
        with pytest.warns(UserWarning) as said:
            w.final_poses(given, steps=3)
        assert (
            "refs has heading -135 rad, a whole number beyond 2π, most likely degrees; headings "
            "are radians: np.radians(-135) = -2.3562"
        ) in [str(r.message) for r in said]
    with pytest.warns(UserWarning, match="init has heading 45 rad"):
        w.rollout([40.0, 20.0, 0.0], init=[0.0, 0.0, 45], steps=3)
    with pytest.warns(UserWarning, match=r"ref has heading 90 rad.*np.radians\(90\) = 1.5708"):
        w.rollout(jnp.array([40.0, 20.0, 90.0]), w.Gains(kr=60.0, k_theta=10.0), steps=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for theta in (0.0, 3.0, -np.pi, 4 * np.pi, 6.0, 361.0, -1e10):  # 1e10: not degrees
            w.rollout([40.0, 20.0, theta], w.Gains(kr=60.0, k_theta=10.0), steps=3)
            w.rollout(jnp.array([40.0, 20.0, theta]), w.Gains(kr=60.0, k_theta=10.0), steps=3)


def test_a_study_warns_of_a_heading_in_degrees_once():
    """The entry points a study calls check its references again: Python's default
    filter still shows the warning once."""
    refs = np.array([[30.0, 30.0, 90.0], [20.0, -10.0, 0.5]])
    loop = w.ClosedLoop("shim-sung", w.Gains(kr=60.0, k_theta=10.0))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("default")
        w.studies.evaluate_loop(loop, refs, horizon=1.0)
    degrees = [str(r.message) for r in said if "most likely degrees" in str(r.message)]
    assert len(degrees) == 1 and degrees[0].startswith("refs has heading 90 rad"), degrees


def test_studies_called_again_do_not_repeat_warnings_already_shown():
    """A study checks its runs ahead of them without touching Python's record of
    the warnings shown: called again, nothing already shown is shown again."""
    refs = np.array([[30.0, 30.0, 90.0], [20.0, -10.0, 0.5]])
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("default")
        warnings.warn("the caller's own", UserWarning, stacklevel=1)
        for _ in range(3):
            w.studies.evaluate_loop(w.Gains(), refs, horizon=1.0)
            w.studies.monte_carlo(jax.random.key(0), n_runs=2, noise_xy=[0.0], noise_deg=[0.0])
    shown = sorted(type(r.message).__name__ for r in said)
    assert shown == ["HeadingUnitsWarning", "UserWarning", "WheelSpeedWarning"], shown


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class _NoGains:
    pass


def test_a_law_without_parameters_runs():
    """A parameter class with no fields is a pytree with no leaves, not an unregistered class."""

    def fixed(pose, ref, params, *, temperature=None, frame=None):
        return _mine(pose, ref, _K(), temperature=temperature, frame=frame)

    law = w.Controller(name="fixed", command=fixed, params_type=_NoGains, validate=lambda p: p)
    final = np.asarray(w.rollout([20.0, 5.0, 0.0], controller=law, steps=150).poses[-1])
    assert np.hypot(final[0] - 20.0, final[1] - 5.0) < 0.1
