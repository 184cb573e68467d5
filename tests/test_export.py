"""The exported C controller against the project: one step, the closed loop, the interface.

The C files of ``wmr_jax.export`` are compiled here with the system C
compiler (present on every machine the suite runs on) and called through
``ctypes``. One step is held to the JAX step built from the project's own
pieces (``motion.ideal_move``, the estimators' ``update``, the law), the law
alone also to the NumPy reference; the closed loop to ``disturbed_metrics``
run by the same disturbances, latencies of several samples included; any
latency up to the C's bound also to the nominal run shifted by the latency,
which perfect compensation must give.
"""

import ctypes
import json
import re
import subprocess
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import export, tuning
from wmr_jax._src.cli.main import main
from wmr_jax._src.model.controllers import get_controller
from wmr_jax._src.model.controllers.schedule import ScheduleParams, knot_radii
from wmr_jax._src.sim import loops, motion
from wmr_jax._src.sim.sensing.disturbances import (
    STANDARD_CONDITIONS,
    Disturbance,
    Measurement,
)
from wmr_jax._src.sim.sensing.estimators import resolve_estimator
from wmr_jax._src.sim.sensing.loop import disturbed_metrics
from wmr_jax._src.studies import conditions

pytestmark = pytest.mark.skipif(export.compiler() is None, reason="no C compiler on this machine")

DATA = "docs/data/standard_conditions.json"
DT = w.DEFAULT_DT


def _saved(tmp_path_factory, label: str) -> str:
    """A tuned_gains.json of the committed standard-conditions results (written as tune does)."""
    from pathlib import Path

    values = json.loads((Path(__file__).parent.parent / DATA).read_text())["gains"][label]
    path = tmp_path_factory.mktemp("gains") / "tuned_gains.json"
    path.write_text(json.dumps(values))
    return str(path)


@pytest.fixture(scope="module")
def robust_file(tmp_path_factory):
    """The default ``tune --robust`` result: a 10-knot schedule with its tuned EKF."""
    return _saved(tmp_path_factory, "robust-tuned")


@pytest.fixture(scope="module")
def fixed_file(tmp_path_factory):
    """A fixed-gain file: the paper's feasible gains (k_r = 60), raw feedback."""
    return _saved(tmp_path_factory, "paper (k_r = 60)")


def _build(tmp_path, loop, *, real="double", **kwargs):
    folder = tmp_path / f"c_{real}"
    export.write_sources(folder, export.c_sources(loop, real=real), loop)
    return export.compile_controller(folder, build=tmp_path / f"build_{real}", **kwargs)


def _state_type(real: str):
    """The ``wmr_controller`` struct as the header defines it, for tests that set its state."""
    r = ctypes.c_double if real == "double" else ctypes.c_float
    return type(
        "State",
        (ctypes.Structure,),
        {
            "_fields_": [
                ("ref", r * 3),
                ("ref_cos", r),
                ("ref_sin", r),
                ("est", r * 5),
                ("cov", r * 6),
                ("sent", (r * 2) * (export.MAX_LATENCY + 1)),
                ("held", r * 2),
                ("latency", ctypes.c_int),
                ("oldest", ctypes.c_int),
                ("started", ctypes.c_int),
            ]
        },
    )


def _random_states(n: int, seed: int):
    """Goals, estimates, filter covariances, measurements and the two commands of a step.

    A tenth of the estimates lie within a few cm of the goal (Regions 0 and 1),
    the rest anywhere within 80 cm; the covariances are the filter's scale
    (σ 0.25 cm, 0.8°) times 0.2 to 3 with correlations up to ±0.5.
    """
    rng = np.random.default_rng(seed)
    refs = np.c_[rng.uniform(-80, 80, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    est = np.c_[rng.uniform(-80, 80, (n, 2)), rng.uniform(-4, 4, n)]
    near = n // 10
    est[:near, :2] = refs[:near, :2] + rng.normal(0, 2, (near, 2))
    meas = est + np.c_[rng.normal(0, 0.5, (n, 2)), rng.normal(0, 0.02, n)]
    applied = np.c_[rng.uniform(-100, 100, n), rng.uniform(-30, 30, n)]
    fresh = np.c_[rng.uniform(-100, 100, n), rng.uniform(-30, 30, n)]
    scale = np.sqrt(np.array([0.25**2, 0.25**2, 0.0145**2]) * rng.uniform(0.2, 3, (n, 3)))
    rho = rng.uniform(-0.5, 0.5, (n, 3))
    corr = np.ones((n, 3, 3))
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        corr[:, i, j] = corr[:, j, i] = rho[:, k]
    p = scale[:, :, None] * corr * scale[:, None, :]
    cov = np.stack([p[:, 0, 0], p[:, 0, 1], p[:, 0, 2], p[:, 1, 1], p[:, 1, 2], p[:, 2, 2]], 1)
    return refs, est, cov, meas, applied, fresh


def _c_step(compiled, real, refs, est, cov, meas, applied, fresh, latency):
    """One ``wmr_step`` of each controller, its state set to the estimate and commands given."""
    state_type = _state_type(real)
    assert ctypes.sizeof(state_type) == compiled.size  # the header's layout
    heading = np.stack([np.asarray(a) for a in w.dynamics.sin_cos(jnp.asarray(est[:, 2]))], 1)
    compiled.start(refs, latency)
    for i in range(len(refs)):
        s = state_type.from_address(compiled.state_address(i))
        s.est[:] = [est[i, 0], est[i, 1], heading[i, 0], heading[i, 1], est[i, 2]]
        s.cov[:] = list(cov[i])
        s.sent[0][:] = list(applied[i])  # acted over the period just ended
        if latency == 1:
            s.sent[1][:] = list(fresh[i])  # in flight
        s.started = 1
    return compiled.step(meas)


def _jax_step(loop, refs, est, cov, meas, applied, fresh, latency):
    """The JAX step of the disturbed loop from the same state (``sensing.loop.disturbed_run``)."""
    estimator, estimate = resolve_estimator(loop.estimator)
    options = loops.Options(controller=get_controller(loop.controller))
    robot = loop.robot or w.Robot()
    dt = jnp.float64(DT)

    def one(ref, e, p, z, acted, flight):
        pose, sensed = motion.SplitPose.of(e), motion.SplitPose.of(z)
        measurement = Measurement(sensed.position, sensed.heading, jnp.float64(0.0), z[2])
        law_input = sensed
        if estimator is not None:
            predicted = motion.ideal_move(pose, motion.ArcMove.of(acted[0], acted[1], dt))
            state = estimator.start(pose, estimate, robot)
            if estimator.name == "ekf":
                state = state._replace(covariance=p)
            command = jax.lax.complex(acted[0], acted[1])
            state = estimator.update(
                state, predicted, command, measurement, ref, estimate, robot, dt
            )
            law_input = state.pose
            if latency == 1 and estimate.compensate:
                law_input = motion.ideal_move(
                    law_input, motion.ArcMove.of(flight[0], flight[1], dt)
                )
        c = motion.split_command(law_input, ref, loop.params, options)
        return jnp.stack([c.real, c.imag])

    args = (refs, est, cov, meas, applied, fresh)
    return np.asarray(jax.jit(jax.vmap(one))(*(jnp.asarray(a) for a in args)))


def _relative(c_cmd, jax_cmd):
    """|C − JAX| relative to the command, floored at 1 (cm/s for v, rad/s for ω)."""
    return np.abs(c_cmd - jax_cmd) / np.maximum(np.abs(jax_cmd), 1.0)


# ---------------------------------------------------------------- the files


@pytest.mark.parametrize("real", export.REALS)
@pytest.mark.parametrize(
    "label, estimator",
    [("robust", None), ("robust", "observer"), ("robust", "ekf"), ("fixed", None)]
    + [("fixed", w.studies.ObserverParams(position=0.4, heading=0.6, compensate=False))],
)
def test_files_compile_clean_and_stand_alone(
    tmp_path, robust_file, fixed_file, label, estimator, real
):
    loop = w.load_tuned(robust_file if label == "robust" else fixed_file)
    loop = loop._replace(estimator=estimator)
    sources = export.c_sources(loop, real=real)
    folder = tmp_path / "c"
    export.write_sources(folder, sources, loop)
    # C99, warnings as errors: the flags the files promise.
    done = subprocess.run(
        [export.compiler(), *export.CFLAGS, "-c", str(folder / "wmr_controller.c"),
         "-o", str(tmp_path / "w.o")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    text = sources.header + sources.source
    includes = set(re.findall(r"#include\s+[<\"]([^>\"]+)[>\"]", text))
    assert includes == {"math.h", "stddef.h", "wmr_controller.h"}
    assert not re.search(
        r"\b(malloc|calloc|realloc|free|printf|static\s+wmr_real\s+\w+\s*[=;\[])", text
    )
    # No state outside the struct: every file-scope definition is a function.
    nm = subprocess.run(["nm", str(tmp_path / "w.o")], capture_output=True, text=True)
    if nm.returncode == 0:
        kinds = {line.split()[-2] for line in nm.stdout.splitlines() if len(line.split()) == 3}
        assert not kinds & set("BbDdCc"), nm.stdout  # no data, bss or common symbols
    assert f"typedef {real} wmr_real;" in sources.header


def test_an_exported_folder_is_named_in_what_its_loop_says(tmp_path, capsys):
    """exported_loop reads the saved gains as load_tuned does, naming the folder and its file."""
    metres = w.Robot(half_track=0.08, v_max=0.22)
    gains = tmp_path / "m.json"
    gains.write_text(json.dumps(tuning.tuned_json(w.Gains(kr=0.1, k_theta=1.0), robot=metres)))
    out = tmp_path / "ctl"
    assert main(["export", "--gains", str(gains), "--out", str(out)]) == 0
    assert f"warning: {str(gains)!r}: robot: half_track = 0.08 cm" in capsys.readouterr().err
    where = f"folder {str(out)!r}: wmr_controller.json"
    with pytest.warns(w.RobotUnitsWarning) as caught:
        loop, _ = export.exported_loop(out)
    assert loop.robot.half_track == 0.08
    assert [str(c.message).split(" is outside")[0] for c in caught] == [
        f"{where}: robot: half_track = 0.08 cm",
        f"{where}: robot: v_max = 0.22 cm/s",
    ]
    # A baseline's folder records its robot in its own block: flagged the same way.
    controller, params = _BASELINES[0]
    baseline = w.ClosedLoop(controller, params, None, metres)
    export.write_sources(tmp_path / "b", export.c_sources(baseline), baseline)
    with pytest.warns(w.RobotUnitsWarning, match=f"^folder {str(tmp_path / 'b')!r}: wmr_contr"):
        assert export.exported_loop(tmp_path / "b")[0].robot.v_max == 0.22
    meta = json.loads((out / "wmr_controller.json").read_text())
    meta["gains"]["kr"] = "fast"
    (out / "wmr_controller.json").write_text(json.dumps(meta))
    with pytest.warns(w.RobotUnitsWarning), pytest.raises(ValueError) as info:
        export.exported_loop(out)
    assert str(info.value) == f"{where}: kr = 'fast' is not allowed; allowed: a number"


def test_export_command_writes_the_files_and_refuses_bad_flags(tmp_path, robust_file, capsys):
    out = tmp_path / "ctl"
    assert main(["export", "--gains", robust_file, "--out", str(out), "--real", "float"]) == 0
    printed = capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == {
        "wmr_controller.h", "wmr_controller.c", "wmr_controller.json"
    }  # fmt: skip
    size = int(re.search(r"sizeof\(wmr_controller\) = (\d+) bytes", printed).group(1))
    compiled = export.compile_controller(out, build=tmp_path / "b")
    assert compiled.size == size and compiled.period == DT
    loop, meta = export.exported_loop(out)
    assert meta["real"] == "float" and isinstance(loop.params, ScheduleParams)
    assert main(["export", "--gains", robust_file, "--out", str(out), "--real", "half"]) == 2
    assert "--real 'half' is not allowed; allowed: double, float" in capsys.readouterr().err
    assert meta["period_s"] == DT  # the project's period unless --period says otherwise
    for bad in ("0", "-0.01", "nan", "inf", "fast"):
        assert main(["export", "--gains", robust_file, "--out", str(out), "--period", bad]) == 2
        err = capsys.readouterr().err
        assert f"--period {bad!r} is not allowed; allowed: a finite number > 0 s" in err
    # A file that is no gains file is named as the other commands name it.
    (tmp_path / "refs.csv").write_text("x,y,theta\n1,2,3\n")
    assert main(["export", "--gains", str(tmp_path / "refs.csv"), "--out", str(out)]) == 2
    assert capsys.readouterr().err.startswith(
        f"wmr-jax: error: --gains '{tmp_path / 'refs.csv'}' is not a JSON gains file (not JSON"
    )


def test_a_period_the_law_cannot_settle_at_is_refused(tmp_path, robust_file, capsys, monkeypatch):
    # 33 for 0.033: milliseconds read as seconds. A good export is left as it was.
    from wmr_jax._src.cli import main as cli

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    out = tmp_path / "ctl"
    assert main(["export", "--gains", robust_file, "--out", str(out)]) == 0
    assert "cannot settle" not in (err := capsys.readouterr().err) and "milliseconds" not in err
    written = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(["export", "--gains", robust_file, "--out", str(out), "--period", "33"]) == 2
    err = capsys.readouterr().err
    assert "warning: --period 33 is read in s; a value in milliseconds needs /1000" in err
    assert f"error: --period 33 is not allowed for {robust_file}: k_theta*dt = " in err
    assert (
        "cannot settle unless both are below 2 (docs/model.md §4); dt = 33 is in s (a period "
        "in milliseconds needs /1000); allowed: a period"
    ) in err
    # The longest period they settle at, to the 4 digits shown: the law's own check
    # passes 0.1 % below it and warns 0.1 % above.
    from wmr_jax._src.model.params import SamplingWarning

    longest = float(re.search(r"allowed: a period below ([0-9.e-]+) s, at which", err)[1])
    loop = w.load_tuned(robust_file)
    check = get_controller(loop.controller).check_sampling
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check(loop.params, 0.999 * longest)
    with pytest.warns(SamplingWarning):
        check(loop.params, 1.001 * longest)
    assert 0.033 < longest < 33
    assert {p.name: p.read_bytes() for p in out.iterdir()} == written


def test_gains_beyond_the_wheel_budget_are_warned_of_as_a_rollout_warns(
    tmp_path, fixed_file, capsys, monkeypatch
):
    from wmr_jax._src.cli import main as cli

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    over = tmp_path / "over.json"
    over.write_text(json.dumps({"kr": 120.0, "k_theta": 10.0}))
    assert main(["export", "--gains", str(over), "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "warning: --gains: k_r + L*k_theta = 138.5 cm/s exceeds v_max = 125 cm/s" in err
    argv = ["--out", str(tmp_path / "b"), "--robot", "turtlebot3-burger"]
    assert main(["export", "--gains", str(over), *argv]) == 0
    assert "k_r + L*k_theta = 200 cm/s exceeds v_max = 22.72 cm/s" in capsys.readouterr().err
    assert main(["export", "--gains", fixed_file, "--out", str(tmp_path / "c")]) == 0
    assert "exceeds" not in capsys.readouterr().err  # tuned within the budget


def test_export_period_is_baked_in_and_recorded(tmp_path, robust_file):
    """``--period 0.02``: the C predicts and limits over 0.02 s, so in the disturbed loop run at
    0.02 s it arrives when the JAX loop at 0.02 s does; the JSON records the period."""
    out = tmp_path / "ctl"
    assert main(["export", "--gains", robust_file, "--out", str(out), "--period", "0.02"]) == 0
    compiled = export.compile_controller(out, build=tmp_path / "b")
    loop, meta = export.exported_loop(out)
    assert compiled.period == 0.02 and meta["period_s"] == 0.02
    robot = loop.robot or w.Robot()
    refs = w.sample_poses(2003, 40)
    refs, noise, factors, _ = conditions._runs(
        refs, jax.random.key(0), robot, None, 0.02, 0.03, True
    )
    spec = conditions._scaled(refs, noise, factors, 0.5, 1.0, True)
    jax_m = disturbed_metrics(
        spec, loop.params, controller=loop.controller, estimator=loop.estimator, robot=robot,
        dt=0.02,
    )  # fmt: skip
    c_m = export.compiled_metrics(compiled, spec, loop, robot=robot, dt=0.02)
    assert jax_m.success.mean() > 0.9
    np.testing.assert_array_equal(c_m.arrival, jax_m.arrival)
    with pytest.raises(ValueError, match="the compiled controller's period, 0.02 s"):
        export.compiled_metrics(compiled, spec, loop, robot=robot)  # at the default 0.033 s


def test_a_library_built_in_a_temporary_folder_goes_with_its_controller(tmp_path, fixed_file):
    """Without ``build``, the library's folder is removed when the controller is, silently
    (the CLI shows every warning; a collected TemporaryDirectory warned)."""
    import gc
    import warnings

    loop = w.load_tuned(fixed_file)
    export.write_sources(tmp_path / "c", export.c_sources(loop), loop)
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        compiled = export.compile_controller(tmp_path / "c")
        scratch = compiled.library.parent
        assert scratch.is_dir() and compiled.period == DT
        del compiled
        gc.collect()
    assert not scratch.exists()
    assert [str(x.message) for x in shown] == []


def test_c_sources_refuses_what_it_cannot_write():
    loop = w.ClosedLoop(w.controllers.SHIM_SUNG, w.Gains())
    with pytest.raises(ValueError, match="real = 'long' is not allowed"):
        export.c_sources(loop, real="long")
    with pytest.raises(ValueError, match="loop.controller = 'aicardi' with Gains is not allowed"):
        export.c_sources(w.ClosedLoop(w.controllers.AICARDI, w.Gains()))
    with pytest.raises(ValueError, match="period = 0"):
        export.c_sources(loop, period=0)
    with pytest.raises(ValueError, match="loop is a Gains"):
        export.c_sources(w.Gains())
    with pytest.raises(ValueError, match="one value"):
        export.c_sources(w.ClosedLoop(w.controllers.SHIM_SUNG, w.Gains(kr=np.array([60.0, 70.0]))))


# ---------------------------------------------------------------- one step


@pytest.mark.parametrize(
    "label, estimator, latency",
    [("robust", "ekf", 1), ("robust", "ekf", 0), ("fixed", "observer", 1), ("fixed", None, 0)]
    + [("fixed", w.studies.ObserverParams(position=0.4, heading=0.6, compensate=False), 1)]
    + [("robust", w.studies.EKFParams(wheel_error=0.05, compensate=False), 1)],
)
def test_one_step_equals_the_jax_step(tmp_path, robust_file, fixed_file, label, estimator, latency):
    """10⁴ random states, double: 1e-12 relative (measured: about 1e-13)."""
    loop = w.load_tuned(robust_file if label == "robust" else fixed_file)
    loop = loop._replace(estimator=estimator)
    compiled = _build(tmp_path, loop)
    states = _random_states(10_000, seed=7)
    c_cmd = _c_step(compiled, "double", *states, latency)
    jax_cmd = _jax_step(loop, *states, latency)
    # Rounding (ISO C rounds every operation; XLA fuses some into FMAs) is
    # amplified by the filter's gain and the law near the goal by ~1e3.
    assert np.max(_relative(c_cmd, jax_cmd)) < 1e-12


def test_float_build_is_within_1e4_of_the_double_jax_step(tmp_path, robust_file):
    loop = w.load_tuned(robust_file)
    compiled = _build(tmp_path, loop, real="float")
    states = _random_states(10_000, seed=8)
    c_cmd = _c_step(compiled, "float", *states, 1)
    jax_cmd = _jax_step(loop, *states, 1)
    rel = _relative(c_cmd, jax_cmd)
    # float's 6e-8 of an 80 cm position is 5e-6 cm; near the goal the law's
    # turn rate moves by k_θ/r_e per cm of it: ~1e-4 rad/s at r_e ~ 1 cm.
    assert np.quantile(rel, 0.999) < 1e-4
    full_scale = np.array([loop.params.v_max, loop.params.v_max / loop.params.half_track])
    assert np.max(np.abs(c_cmd - jax_cmd) / full_scale) < 1e-5


def _boundary_states(params, seed=1):
    """Goals and measured poses on the law's switches: r_e at R_e, R_a, R_m and each knot
    (and one ulp either side), φ_e at 0, ±Φ_m, ±(π − Φ_m), π/2, π, θ_e at 0, ±π/2, π, and
    poses exactly at the goal. The axis-aligned ones are exact in floating point."""
    rng = np.random.default_rng(seed)
    radii = [float(params.r_e), float(params.r_a), float(params.r_m)]
    if isinstance(params, ScheduleParams):
        radii += list(knot_radii(len(params.kr)))
    phi_m = float(params.phi_m)
    rows = []
    for radius in radii:
        for r in (radius, np.nextafter(radius, 0), np.nextafter(radius, 1e9)):
            for phi in (0.0, np.pi, phi_m, -phi_m, np.pi - phi_m, phi_m - np.pi, np.pi / 2):
                for th in (0.0, np.pi / 2, -np.pi / 2, np.pi, rng.uniform(-np.pi, np.pi)):
                    heading = rng.uniform(-np.pi, np.pi)
                    ref = np.array([*rng.uniform(-50, 50, 2), heading + th])
                    e = r * np.array([np.cos(phi), np.sin(phi)])
                    c, s = np.cos(heading), np.sin(heading)
                    d = np.array([c * e[0] - s * e[1], s * e[0] + c * e[1]])
                    rows.append((ref, np.array([ref[0] - d[0], ref[1] - d[1], heading])))
                    rows.append((np.array([*e, th]), np.zeros(3)))  # exact
    for _ in range(200):
        ref = rng.uniform(-80, 80, 3)
        rows.append((ref, ref.copy()))
    return np.array([a for a, _ in rows]), np.array([b for _, b in rows])


@pytest.mark.parametrize("label", ["robust", "fixed"])
def test_law_on_its_switches_and_at_the_goal(tmp_path, robust_file, fixed_file, label):
    """On a switch one rounding decides the region: with XLA's FMAs (``contract``) the C
    rounds as the JAX step does and takes the same side every time."""
    loop = w.load_tuned(robust_file if label == "robust" else fixed_file)._replace(estimator=None)
    try:
        compiled = _build(tmp_path, loop, contract=True)
    except RuntimeError as err:
        pytest.skip(f"the compiler cannot build for this CPU's FMAs: {err}")
    refs, meas = _boundary_states(loop.params)
    compiled.start(refs, 0)
    c_cmd = compiled.step(meas)
    options = loops.Options(controller=get_controller(loop.controller))

    def one(ref, z):
        c = motion.split_command(motion.SplitPose.of(z), ref, loop.params, options)
        return jnp.stack([c.real, c.imag])

    jax_cmd = np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(refs), jnp.asarray(meas)))
    assert np.max(_relative(c_cmd, jax_cmd)) < 1e-12
    at_goal = np.all(refs == meas, axis=1)
    # θ_e = 0 and r_e = 0: no command, but for the rounding of sin θ_e (~1e-16).
    np.testing.assert_allclose(c_cmd[at_goal], 0.0, rtol=0, atol=1e-12)


def test_fixed_law_equals_the_numpy_reference(tmp_path, fixed_file):
    """The raw-feedback law against ``reference_control`` (angles and atan2), 1e-9 relative."""
    loop = w.load_tuned(fixed_file)
    compiled = _build(tmp_path, loop)
    rng = np.random.default_rng(3)
    refs = np.c_[rng.uniform(-80, 80, (2000, 2)), rng.uniform(-np.pi, np.pi, 2000)]
    meas = np.c_[rng.uniform(-80, 80, (2000, 2)), rng.uniform(-np.pi, np.pi, 2000)]
    meas[:500, :2] = refs[:500, :2] + rng.normal(0, 3, (500, 2))
    compiled.start(refs, 0)
    c_cmd = compiled.step(meas)
    expected = np.array(
        [w.studies.reference_control(m, r, loop.params) for m, r in zip(meas, refs, strict=True)]
    )
    ok = _relative(c_cmd, expected) < 1e-9
    # The reference's atan2 may put a pose within rounding of a switch on its other side.
    assert ok.all(axis=1).mean() > 0.999


# ---------------------------------------------------------------- the closed loop


def _conditions_runs(loop, n, seed=0):
    robot = loop.robot or w.Robot()
    refs = w.sample_poses(2003, n)
    return robot, conditions._runs(refs, jax.random.key(seed), robot, None, DT, 0.03, True)


@pytest.mark.parametrize("label", ["robust", "fixed"])
def test_closed_loop_arrives_when_the_jax_loop_does(tmp_path, robust_file, fixed_file, label):
    """Each standard condition, 3 % wheel mismatch: the same arrival time on ≥ 99.9 % of runs."""
    loop = w.load_tuned(robust_file if label == "robust" else fixed_file)
    compiled = _build(tmp_path, loop)
    robot, (refs, noise, factors, _) = _conditions_runs(loop, 150)
    for name, sxy, sdeg, latency in STANDARD_CONDITIONS:
        spec = conditions._scaled(refs, noise, factors, sxy, sdeg, latency)
        jax_m = disturbed_metrics(
            spec, loop.params, controller=loop.controller, estimator=loop.estimator, robot=robot
        )
        c_m = export.compiled_metrics(compiled, spec, loop, robot=robot)
        same = (jax_m.arrival == c_m.arrival) | ~(jax_m.success | c_m.success)
        assert same.mean() >= 0.999, (name, same.mean())
        if label == "robust":
            assert c_m.success.mean() > 0.9, name  # the runs compared do arrive


def test_closed_loop_latency_beyond_one_against_jax(tmp_path, robust_file):
    """m = 2, 3 and 5 samples of latency (100 runs each, one batch: a latency per run),
    compensated over the m commands in flight on both sides."""
    loop = w.load_tuned(robust_file)
    compiled = _build(tmp_path, loop)
    latencies = np.repeat([2.0, 3.0, 5.0], 100)
    robot, (refs, noise, factors, _) = _conditions_runs(loop, len(latencies))
    spec = conditions._scaled(refs, noise, factors, 0.5, 1.0, False)._replace(delay=latencies)
    jax_m = disturbed_metrics(
        spec, loop.params, controller=loop.controller, estimator=loop.estimator, robot=robot
    )
    c_m = export.compiled_metrics(compiled, spec, loop, robot=robot)
    same = (jax_m.arrival == c_m.arrival) | ~(jax_m.success | c_m.success)
    for m in (2.0, 3.0, 5.0):
        assert same[latencies == m].mean() >= 0.999, m


@pytest.mark.parametrize("estimator", ["ekf", "observer"])
def test_any_latency_is_the_nominal_run_shifted(tmp_path, robust_file, estimator):
    """The model robot, exact measurements: compensation predicts the pose at which each
    command acts exactly, so under m periods of latency the robot stands still for m
    periods and then drives the nominal run (``disturbed_metrics``, no latency)."""
    loop = w.load_tuned(robust_file)._replace(estimator=estimator)
    compiled = _build(tmp_path, loop)
    # The runs of the closed-loop test above: with the EKF, its compiled JAX loop.
    robot, (refs, noise, _, _) = _conditions_runs(loop, 150)
    nominal = Disturbance(refs, 0 * noise, np.ones((len(refs), 3)), np.float64(0.0))
    expected = disturbed_metrics(
        nominal, loop.params, controller=loop.controller, estimator=estimator, robot=robot
    )
    assert expected.success.all()
    for m in (0, 1, 2, 5, export.MAX_LATENCY):
        c_m = export.compiled_metrics(compiled, nominal._replace(delay=float(m)), loop, robot=robot)
        arrived = expected.arrival + m * DT <= (noise.shape[1] - 1) * DT
        np.testing.assert_allclose(
            c_m.arrival[arrived], expected.arrival[arrived] + m * DT, rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(c_m.path[arrived], expected.path[arrived], rtol=1e-9, atol=1e-9)


def test_latency_outside_the_bound_is_clamped(tmp_path, robust_file):
    loop = w.load_tuned(robust_file)
    compiled = _build(tmp_path, loop)
    refs = np.tile([[30.0, 20.0, 1.0]], (4, 1))
    compiled.start(refs, np.array([export.MAX_LATENCY, export.MAX_LATENCY + 5, 0, -3]))
    pose = np.zeros((4, 3))
    sent = []
    for _ in range(30):  # the commands alone, the robot held still: the same sequence per pair
        sent.append(compiled.step(pose))
    sent = np.array(sent)
    np.testing.assert_array_equal(sent[:, 0], sent[:, 1])
    np.testing.assert_array_equal(sent[:, 2], sent[:, 3])
    assert not np.array_equal(sent[:, 0], sent[:, 2])


def test_evaluate_c_judges_the_compiled_controller_as_the_file(tmp_path, robust_file, capsys):
    out = tmp_path / "ctl"
    assert main(["export", "--gains", robust_file, "--out", str(out)]) == 0
    refs = tmp_path / "refs.npy"
    # As many runs as the closed-loop test above: the JAX side reuses its compiled loop.
    np.save(refs, w.sample_poses(11, 150))
    common = ["--refs", str(refs), "--condition", "both"]
    capsys.readouterr()
    per_ref = ["--per-ref", str(tmp_path / "c.csv")]
    assert (
        main(["evaluate", "--c", str(out), *common, *per_ref, "--json", str(tmp_path / "c.json")])
        == 0
    )
    c_out = capsys.readouterr().out
    assert (
        main(["evaluate", "--gains", robust_file, *common, "--json", str(tmp_path / "j.json")]) == 0
    )
    j_out = capsys.readouterr().out
    c_result = json.loads((tmp_path / "c.json").read_text())
    j_result = json.loads((tmp_path / "j.json").read_text())
    for key in ("success", "mean_arrival_s", "median_arrival_s", "peak_wheel_speed", "n"):
        assert c_result[key] == pytest.approx(j_result[key], rel=1e-9), key
    assert c_result["feedback"] == "ekf" and "compiled C" in c_result["controller"]
    # Run by run, as the JAX loop's; and so the same table rows, "not arrived" included.
    assert len(c_result["per_reference"]) == 150
    for c_run, j_run in zip(c_result["per_reference"], j_result["per_reference"], strict=True):
        assert c_run["ref"] == j_run["ref"] and c_run["success"] == j_run["success"]
        assert c_run["final_distance_cm"] == pytest.approx(j_run["final_distance_cm"], abs=1e-9)
    c_rows = [line.split("|")[1] for line in c_out.splitlines() if line.startswith("| ")]
    j_rows = [line.split("|")[1] for line in j_out.splitlines() if line.startswith("| ")]
    assert c_rows == j_rows and " not arrived " in c_rows
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert len(lines) == 1 + 150 and lines[1].startswith("row 0 (from 0),")
    assert main(["evaluate", "--c", str(out), *common, "--estimator", "observer"]) == 2
    assert "--estimator is not allowed with --c" in capsys.readouterr().err
    assert main(["evaluate", "--c", str(tmp_path), *common]) == 2
    err = capsys.readouterr().err
    assert f"--c: folder {str(tmp_path)!r} cannot be read: wmr_controller.json: there is no " in err
    with pytest.raises(ValueError, match=r"^folder '.*' cannot be read: wmr_controller\.json"):
        export.exported_loop(tmp_path)  # the library names its argument, not the flag
    assert main(["evaluate", *common]) == 2
    assert "--gains is required" in capsys.readouterr().err


# ---------------------------------------------------------------- sanitizers


_SANITIZED_MAIN = r"""
#include <math.h>
#include <stdio.h>
#include "wmr_controller.h"

/* A host loop: the ideal robot on its exact arc, each latency 0 .. WMR_MAX_LATENCY + 2. */
int main(void)
{
    int latency, k, arrived = 0;
    for (latency = -1; latency <= WMR_MAX_LATENCY + 2; ++latency) {
        wmr_controller c;
        double ref[3] = {30.0, -20.0, 1.0}, pose[3] = {0.0, 0.0, 0.0}, cmd[2];
        double queue[64][2] = {{0.0, 0.0}};
        double dt = wmr_period();
        wmr_init(&c, ref, latency);
        for (k = 0; k < 400; ++k) {
            int m = latency < 0 ? 0 : (latency > WMR_MAX_LATENCY ? WMR_MAX_LATENCY : latency);
            double v, w, h;
            wmr_step(&c, pose, cmd);
            queue[(k + m) % 64][0] = cmd[0];
            queue[(k + m) % 64][1] = cmd[1];
            v = queue[k % 64][0];
            w = queue[k % 64][1];
            queue[k % 64][0] = queue[k % 64][1] = 0.0;
            h = pose[2] + 0.5 * w * dt;
            pose[0] += v * dt * cos(h);
            pose[1] += v * dt * sin(h);
            pose[2] += w * dt;
        }
        arrived += hypot(pose[0] - ref[0], pose[1] - ref[1]) < 1.0;
    }
    printf("%d\n", arrived);
    return 0;
}
"""


@pytest.mark.skipif(not export.sanitizers_work(), reason="the C compiler has no ASan/UBSan")
def test_clean_under_address_and_undefined_sanitizers(tmp_path, robust_file):
    loop = w.load_tuned(robust_file)
    folder = tmp_path / "c"
    export.write_sources(folder, export.c_sources(loop), loop)
    (tmp_path / "host.c").write_text(_SANITIZED_MAIN)
    exe = tmp_path / "host"
    flags = ["-std=c99", "-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
    subprocess.run(
        [export.compiler(), *flags, f"-I{folder}", str(folder / "wmr_controller.c"),
         str(tmp_path / "host.c"), "-o", str(exe), "-lm"],
        check=True,
    )  # fmt: skip
    done = subprocess.run([str(exe)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert int(done.stdout) == export.MAX_LATENCY + 4  # every latency arrived


def test_bench_times_the_c_step(tmp_path):
    config = w.studies.BenchConfig(
        sizes=(50,), steps=20, repeats=1, dtype="float64", cases=("c_controller",)
    )
    (row,) = w.studies.run_benchmark(config)["rows"]
    assert row["case"] == "c_controller" and row["ns_per_step"] > 0
    assert row["robot_steps_per_s"] == pytest.approx(1e9 / row["ns_per_step"])
    loop = w.ClosedLoop(
        w.tuning.SCHEDULE, w.tuning.ScheduleParams.from_gains(w.Gains()), "ekf", w.Robot()
    )
    assert row["state_bytes"] == _build(tmp_path, loop).size


_SIMULATED_ROBOT = r"""
#include <math.h>
#include <stdio.h>
#include "wmr_controller.h"

void drive_to(double x, double y, double theta, int latency, int periods);

/* The robot the page's loop drives: the ideal robot on its exact arc, one
   period of latency (a command acts from the period after it is sent). */
static double robot[3], applied[2], pending[2];

void read_pose(double pose[3]) { pose[0] = robot[0]; pose[1] = robot[1]; pose[2] = robot[2]; }

void send_command(const double command[2]) { pending[0] = command[0]; pending[1] = command[1]; }

void wait_for_next_period(void)
{
    double dt = wmr_period(), u = 0.5 * applied[1] * dt;
    double chord = applied[0] * dt * (fabs(u) > 1e-12 ? sin(u) / u : 1.0);
    robot[0] += chord * cos(robot[2] + u);
    robot[1] += chord * sin(robot[2] + u);
    robot[2] += applied[1] * dt;
    applied[0] = pending[0];
    applied[1] = pending[1];
}

int main(void)
{
    drive_to(30.0, 20.0, 1.0, 1, 300);
    printf("%.6f %.6f %.6f\n", robot[0], robot[1], robot[2]);
    return 0;
}
"""


def test_the_deploy_pages_host_loop_drives_a_robot_to_its_goal(tmp_path, robust_file):
    """docs/deploy.md's C loop, as written, against a simulated robot with one period of latency."""
    from pathlib import Path

    page = (Path(__file__).parent.parent / "docs" / "deploy.md").read_text(encoding="utf-8")
    (block,) = [b for b in re.findall(r"```c\n(.*?)```", page, re.S) if "drive_to" in b]
    loop = w.load_tuned(robust_file)
    folder = tmp_path / "c"
    export.write_sources(folder, export.c_sources(loop), loop)
    (tmp_path / "loop.c").write_text(block)
    (tmp_path / "robot.c").write_text(_SIMULATED_ROBOT)
    exe = tmp_path / "host"
    sources = [folder / "wmr_controller.c", tmp_path / "loop.c", tmp_path / "robot.c"]
    subprocess.run(
        [
            export.compiler(),
            *export.CFLAGS,
            f"-I{folder}",
            *map(str, sources),
            "-o",
            str(exe),
            "-lm",
        ],
        check=True,
    )
    final = np.array(
        subprocess.run([str(exe)], capture_output=True, text=True).stdout.split(), float
    )
    # Arrived as docs/model.md §6 counts it: within 1 cm and 5° of the goal.
    assert np.hypot(final[0] - 30.0, final[1] - 20.0) <= w.studies.DEFAULT_TOL_R
    assert abs(np.angle(np.exp(1j * (final[2] - 1.0)))) <= w.studies.DEFAULT_TOL_THETA


@pytest.mark.parametrize("velocity", ["ideal", "nonideal"])
def test_closed_loop_with_a_speed_limiter_and_the_wheel_loop(tmp_path, fixed_file, velocity):
    """A robot whose limiter binds (docs/model.md §4.2.2) in the ideal loop: the C limits
    what it sends as the loop's limiter does, and predicts with it. The non-ideal wheel
    loop (which models no limiter) on the robot without one."""
    limited = w.Robot(accel_max=400.0, angular_accel_max=60.0)
    robot = limited if velocity == "ideal" else w.Robot()
    loop = w.load_tuned(fixed_file)._replace(estimator="ekf", robot=robot)
    compiled = _build(tmp_path, loop)
    _, (refs, noise, factors, _) = _conditions_runs(loop, 40)
    spec = conditions._scaled(refs, noise, factors, 0.5, 1.0, True)
    jax_m = disturbed_metrics(spec, loop.params, estimator="ekf", robot=robot, velocity=velocity)
    c_m = export.compiled_metrics(compiled, spec, loop, robot=robot, velocity=velocity)
    assert jax_m.success.mean() > 0.9
    np.testing.assert_array_equal(c_m.arrival, jax_m.arrival)
    np.testing.assert_allclose(c_m.path, jax_m.path, rtol=1e-9)
    if velocity == "nonideal":
        with pytest.raises(ValueError, match="velocity = 'nonideal' is not allowed"):
            limited_loop = loop._replace(robot=limited)
            export.compiled_metrics(compiled, spec, limited_loop, robot=limited, velocity=velocity)


@pytest.mark.parametrize("estimator", ["ekf", "observer"])
def test_compensation_through_a_binding_speed_limiter_beyond_one_period(
    tmp_path, fixed_file, estimator
):
    """Three periods of latency on a robot whose limiter binds: both sides roll the estimate
    over the three commands in flight as the limiter will let them through."""
    limited = w.Robot(accel_max=400.0, angular_accel_max=60.0)
    loop = w.load_tuned(fixed_file)._replace(estimator=estimator, robot=limited)
    compiled = _build(tmp_path, loop)
    _, (refs, noise, factors, _) = _conditions_runs(loop, 40)
    spec = conditions._scaled(refs, noise, factors, 0.5, 1.0, False)._replace(delay=3.0)
    jax_m = disturbed_metrics(spec, loop.params, estimator=estimator, robot=limited)
    c_m = export.compiled_metrics(compiled, spec, loop, robot=limited)
    assert jax_m.success.mean() > 0.9
    np.testing.assert_array_equal(c_m.arrival, jax_m.arrival)
    np.testing.assert_allclose(c_m.path, jax_m.path, rtol=1e-9)


_BASELINES = [
    (w.controllers.AICARDI, w.controllers.AicardiGains()),
    (w.controllers.AICARDI, w.controllers.AicardiGains(backward=True)),
    (w.controllers.ASTOLFI, w.controllers.AstolfiGains(backward=False)),
    (w.controllers.ASTOLFI, w.controllers.AstolfiGains()),
]


def _wheel_clipped(cmd, robot):
    """``(v, ω)`` with each rim ``v ∓ L ω`` clipped at ``±V_max`` (where one exceeds it)."""
    half_track, v_max = float(robot.half_track), float(robot.v_max)
    rims = np.stack([cmd[:, 0] - half_track * cmd[:, 1], cmd[:, 0] + half_track * cmd[:, 1]], 1)
    over = np.any(np.abs(rims) > v_max, axis=1)
    rims = np.clip(rims, -v_max, v_max)
    clipped = np.stack([0.5 * rims.sum(1), (rims[:, 1] - rims[:, 0]) / (2 * half_track)], 1)
    return np.where(over[:, None], clipped, cmd)


@pytest.mark.parametrize("controller, gains", _BASELINES)
def test_baseline_laws_equal_the_jax_law_within_the_wheel_limit(tmp_path, controller, gains):
    """Aicardi and Astolfi: the JAX law (atan2 and all), each rim then held within ±V_max as
    the robot holds it (the baselines ask for more far from the goal; the C clips)."""
    loop = w.ClosedLoop(controller, gains)
    compiled = _build(tmp_path, loop)
    rng = np.random.default_rng(5)
    n = 10_000
    refs = np.c_[rng.uniform(-80, 80, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    meas = np.c_[rng.uniform(-80, 80, (n, 2)), rng.uniform(-4, 4, n)]
    meas[:1000, :2] = refs[:1000, :2] + rng.normal(0, 1e-3, (1000, 2))  # at the goal floor
    meas[1000:3000, :2] = refs[1000:3000, :2] + rng.normal(0, 3, (2000, 2))
    compiled.start(refs, 0)
    c_cmd = compiled.step(meas)
    options = loops.Options(controller=controller)

    def one(ref, z):
        c = motion.split_command(motion.SplitPose.of(z), ref, gains, options)
        return jnp.stack([c.real, c.imag])

    jax_cmd = np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(refs), jnp.asarray(meas)))
    expected = _wheel_clipped(jax_cmd, w.Robot())
    assert np.quantile(_relative(c_cmd, expected), 0.999) < 1e-12
    assert np.all(_relative(c_cmd, expected) < 1e-9)  # atan2: libm's against XLA's


def test_baseline_closed_loop_in_the_wheel_loop(tmp_path):
    """The non-ideal loop clips each wheel at ±V_max as the C does: on the model robot, under
    latency, the two loops arrive together (the ideal loop has no wheel limit, §4.2.2)."""
    controller, gains = _BASELINES[2]
    loop = w.ClosedLoop(controller, gains)
    compiled = _build(tmp_path, loop)
    robot, (refs, noise, _, _) = _conditions_runs(loop, 40)  # the draw of the tests above
    spec = Disturbance(refs, 0 * noise, np.ones((len(refs), 3)), np.float64(1.0))
    jax_m = disturbed_metrics(spec, gains, controller=controller, velocity="nonideal")
    c_m = export.compiled_metrics(compiled, spec, loop, robot=robot, velocity="nonideal")
    assert jax_m.success.mean() > 0.5
    np.testing.assert_array_equal(c_m.arrival, jax_m.arrival)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        # A string is no bool: "no" would have built with the sanitizers.
        ({"sanitize": "no"}, "sanitize = 'no' is not allowed; allowed: True or False"),
        ({"contract": 2}, "contract = 2 is not allowed; allowed: True or False"),
        ({"optimise": "-Obogus"}, "optimise = '-Obogus' is not allowed; allowed: -O, -O0"),
        ({"build": 3}, "build = 3 is not allowed; allowed: a path"),
        ({"folder": 3}, "folder = 3 is not allowed; allowed: a path"),
    ],
)
def test_compile_controller_refuses_bad_options_before_compiling(
    tmp_path, monkeypatch, kwargs, message
):
    from wmr_jax._src.export import codegen, compiled

    def compiled_anyway(*args, **kwargs):
        raise AssertionError("the compiler ran with a bad option")

    monkeypatch.setattr(compiled, "_run", compiled_anyway)
    for name in (codegen.HEADER, codegen.SOURCE):  # an exported folder, as far as it looks
        (tmp_path / name).write_text("")
    kwargs = {"folder": tmp_path, "build": tmp_path / "build", **kwargs}
    with pytest.raises(ValueError, match=re.escape(message)):
        export.compile_controller(**kwargs)
