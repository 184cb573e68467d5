"""Identifying the true robot from its logs (wmr_jax._src.identify, docs/model.md §10)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wmr_jax._src.identify import fit, logs, model, plan
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Gains
from wmr_jax._src.model.robots import load_robot
from wmr_jax._src.sim import loops

BASE = load_robot("paper")
DT = 0.04
SIGMA_XY, SIGMA_THETA = 0.3, math.radians(0.5)


def _log(seed, scale, track_factor, gain, latency, minutes=1.0, dt=DT, squares=True):
    commands = plan.plan_commands(BASE, dt, minutes, seed, squares=squares)
    return plan.synthetic_log(
        commands,
        BASE,
        scale,
        float(BASE.half_track) * track_factor,
        gain,
        latency,
        dt,
        SIGMA_XY,
        SIGMA_THETA,
        jax.random.PRNGKey(seed),
    )


def test_replay_with_the_true_parameters_is_the_closed_loop_bit_for_bit():
    """A log written by the Shim–Sung loop on the true robot replays to its poses exactly."""
    steps, latency = 120, 2
    with jax.enable_x64(True):
        robot = model.fitted_robot(
            jax.tree.map(jnp.float64, BASE), float(BASE.half_track) * 1.03, 60.0
        )
        noise = jax.random.normal(jax.random.PRNGKey(3), (steps, 3)) * 0.3
        spec = model.TrueRobot(
            noise,
            jnp.asarray([1.02, 0.985]),
            jnp.float64(BASE.half_track),
            jnp.float64(latency),
            robot.half_track,
            robot.speed_gain,
        )
        options = loops.Options(
            steps=steps,
            velocity="nonideal",
            controller=SHIM_SUNG,
            wheel_integral=False,
            wheel_coriolis=False,
            remat=False,
            max_delay=latency,
        )
        init = jnp.asarray([-40.0, 25.0, 1.0])
        ref = jnp.zeros(3)
        _, _, (poses, out, _) = loops.scan_closed_loop(
            ref, Gains(), init, robot, jnp.float64(DT), options, disturbance=spec, record=True
        )
        applied = np.column_stack([out.v, out.omega])
        assert np.all(applied[:latency] == 0) and np.any(applied[latency:] != 0)
        # The command sent at sample k is the one applied at sample k + m.
        sent = np.vstack([applied[latency:], np.zeros((latency, 2))])
        replayed = model.replay(
            jnp.asarray(sent), init, robot, spec.scale, spec.base_half_track, latency, DT
        )
    assert np.array_equal(np.asarray(replayed), np.asarray(poses))


def test_the_model_moves_the_body_with_the_true_half_track():
    """Straight and on-the-spot commands move as the model's formulas say."""
    dt, steps = 0.05, 200
    scale, track, base_track = (1.01, 0.99), 9.0, 8.0
    commands = np.zeros((steps, 2))
    commands[:100, 0] = 20.0
    commands[100:, 1] = 0.5
    with jax.enable_x64(True):
        robot = model.fitted_robot(
            jax.tree.map(jnp.float64, BASE.replace(half_track=base_track)), track, 200.0
        )
        poses = np.asarray(
            model.replay(
                jnp.asarray(commands), jnp.zeros(3), robot, jnp.asarray(scale), base_track, 0, dt
            )
        )
    # Straight: rims 20·(1.01) and 20·(0.99): v = 20, ω = 20·(0.99 − 1.01)/(2·9).
    omega = 20 * (scale[1] - scale[0]) / (2 * track)
    assert poses[99, 2] == pytest.approx(omega * 100 * dt, rel=2e-2)
    # On the spot: rims ∓0.5·8 scaled: ω = 0.5·8·(1.01 + 0.99)/(2·9).
    turn = (poses[199, 2] - poses[129, 2]) / (70 * dt)
    assert turn == pytest.approx(0.5 * base_track * (scale[0] + scale[1]) / (2 * track), rel=1e-6)


def test_identification_recovers_several_robots_within_the_targets():
    """Two robots, latency 0 and 3, one minute of driving each, fitted in one batch."""
    truths = [
        ((1.012, 0.991), 1.015, 100.0, 0),
        ((0.988, 0.997), 0.99, 90.0, 3),
    ]
    segs = []
    for seed, (scale, track, gain, latency) in zip((0, 3), truths, strict=True):
        commands, measured, _ = _log(seed, scale, track, gain, latency, squares=False)
        segs.append(fit.segments_of(commands, measured))
    found = fit.fit_batch(segs, BASE, DT)
    for (scale, track, gain, latency), got in zip(truths, found, strict=True):
        assert got.latency == latency
        # One minute of driving, not the target's five: twice the target's 0.1 %.
        np.testing.assert_allclose(got.wheel_scale, scale, rtol=2e-3)
        assert got.half_track == pytest.approx(float(BASE.half_track) * track, rel=2e-3)
        assert got.speed_gain == pytest.approx(gain, rel=0.1)
        assert got.sigma_xy == pytest.approx(SIGMA_XY, rel=0.2)
        assert got.sigma_theta == pytest.approx(SIGMA_THETA, rel=0.2)
        lo, hi = got.ci95["half_track"]
        assert lo < got.half_track < hi


@pytest.mark.parametrize("turn", [math.pi - 2e-3, -math.pi + 2e-3, math.pi, 2.0])
def test_a_segment_is_placed_alike_whichever_way_it_heads(turn):
    """Rotating a window's measurements moves none of its residuals, even across ±π.

    Near a half turn the positions' Procrustes angle and the headings' offset
    can fall on either side of the cut; placed apart, the window's residuals
    would be a full turn's worth of heading.
    """
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2.4, 60)
    path = np.column_stack([100 * np.sin(0.8 * t), 100 * (1 - np.cos(0.8 * t)), 0.8 * t])
    noisy = path + rng.normal(0.0, 1.0, path.shape) * [SIGMA_XY, SIGMA_XY, SIGMA_THETA]
    # The first heading's noise alone puts it across the cut from the rest.
    noisy[0, 2] = path[0, 2] + 4e-3

    def placed(angle):
        c, s = math.cos(angle), math.sin(angle)
        moved = np.column_stack(
            [
                c * noisy[:, 0] - s * noisy[:, 1] + 7.0,
                s * noisy[:, 0] + c * noisy[:, 1] - 3.0,
                noisy[:, 2] + angle,
            ]
        )
        with jax.enable_x64(True):
            rx, ry, rt = fit._placed(
                jnp.asarray(path), jnp.asarray(moved), SIGMA_XY**-2, SIGMA_THETA**-2
            )
        # The positions' residuals turn with the measurements: turned back here.
        return np.column_stack([c * rx + s * ry, c * ry - s * rx, rt])

    np.testing.assert_allclose(placed(turn), placed(0.0), atol=1e-6)


def _csv(tmp_path, commands, poses, dt=DT, name="log.csv"):
    path = tmp_path / name
    logs.write_csv(path, dt, commands, poses)
    return path


def test_a_ros2_bag_reads_as_its_csv(tmp_path):
    """Twist and PoseStamped messages at the samples, in m, read back to the CSV's log."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    commands, measured, _ = _log(5, (1.01, 0.99), 1.0, 100.0, 1, minutes=0.2)
    csv_log = logs.read_csv(_csv(tmp_path, commands, measured))
    store = get_typestore(Stores.ROS2_HUMBLE)
    twist_t = store.types["geometry_msgs/msg/Twist"]
    vector = store.types["geometry_msgs/msg/Vector3"]
    pose_t = store.types["geometry_msgs/msg/PoseStamped"]
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    point_t = store.types["geometry_msgs/msg/Point"]
    quat_t = store.types["geometry_msgs/msg/Quaternion"]
    inner_t = store.types["geometry_msgs/msg/Pose"]
    start = 1_700_000_000 * 10**9
    path = tmp_path / "bag"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        cmd = writer.add_connection("/cmd_vel", twist_t.__msgtype__, typestore=store)
        pos = writer.add_connection("/tracker", pose_t.__msgtype__, typestore=store)
        for k, (c, p) in enumerate(zip(commands, measured, strict=True)):
            stamp = start + round(k * DT * 1e9)
            msg = twist_t(vector(c[0] / 100, 0.0, 0.0), vector(0.0, 0.0, c[1]))
            writer.write(cmd, stamp, store.serialize_cdr(msg, twist_t.__msgtype__))
            half = p[2] / 2
            header = header_t(time_t(stamp // 10**9, stamp % 10**9), "map")
            pose = inner_t(
                point_t(p[0] / 100, p[1] / 100, 0.0),
                quat_t(0.0, 0.0, math.sin(half), math.cos(half)),
            )
            writer.write(pos, stamp, store.serialize_cdr(pose_t(header, pose), pose_t.__msgtype__))
    bag_log = logs.read_log(path, cmd_topic="/cmd_vel", pose_topic="/tracker")
    assert bag_log.dt == pytest.approx(DT, rel=1e-9)
    np.testing.assert_allclose(bag_log.commands, csv_log.commands, atol=1e-9)
    np.testing.assert_allclose(bag_log.poses, csv_log.poses, atol=1e-9)
    with pytest.raises(ValueError, match="topic '/odom' is not in the bag"):
        logs.read_log(path, cmd_topic="/cmd_vel", pose_topic="/odom")


@pytest.fixture(scope="module")
def good():
    commands, measured, _ = _log(7, (1.01, 0.99), 1.0, 100.0, 0, minutes=1.5)
    return commands, measured


def _error(path):
    with pytest.raises(ValueError) as info:
        logs.read_csv(path, minimum=50)
    message = str(info.value)
    assert str(path) in message and "\n" not in message
    return message


def test_bad_logs_give_one_clear_error_each(tmp_path, good):
    commands, measured = good
    # Non-uniform time: one step of 1.5 periods at the 11th row (line 12).
    path = _csv(tmp_path, commands, measured, name="ok.csv")
    text = path.read_text().splitlines()
    row = text[11].split(",")
    row[0] = repr(float(row[0]) + DT / 2)
    text[11] = ",".join(row)
    (tmp_path / "time.csv").write_text("\n".join(text) + "\n")
    message = _error(tmp_path / "time.csv")
    assert "line 12: t = " in message and "uniform" in message
    assert "np." not in message  # plain numbers, not NumPy's repr
    # Too short.
    assert "too short" in _error(_csv(tmp_path, commands[:20], measured[:20], name="short.csv"))
    # NaN at line 6.
    bad = measured.copy()
    bad[4, 1] = np.nan
    message = _error(_csv(tmp_path, commands, bad, name="nan.csv"))
    assert "line 6" in message and "y = nan" in message
    # Metres and m/s.
    metres = measured.copy()
    metres[:, :2] /= 100
    # (The files' names say nothing: each message is told apart by its own words.)
    message = _error(_csv(tmp_path, commands, metres, name="a.csv"))
    assert "times the distance v_cmd asked for: the poses look like metres" in message
    fast = commands.copy()
    fast[:, 0] /= 100
    message = _error(_csv(tmp_path, fast, measured, name="b.csv"))
    assert "times the distance v_cmd asked for: v_cmd looks like m/s" in message
    # Degrees, wrapped to ±180 as trackers write them.
    degrees = measured.copy()
    degrees[:, 2] = (np.rad2deg(degrees[:, 2]) + 180) % 360 - 180
    turns_57 = "theta turns about 57 times what omega_cmd asks for: it looks like degrees"
    assert turns_57 in _error(_csv(tmp_path, commands, degrees, name="c.csv"))
    # ... or unwrapped, over minutes in which the heading drifts from the integrated command
    # (here by turns that miss their mark): decided step by step, not on the whole turn.
    drifting = measured.copy()
    drifting[:, 2] = np.unwrap(drifting[:, 2]) + np.cumsum(np.abs(commands[:, 1])) * DT / 2
    path = _csv(tmp_path, commands, drifting, name="d.csv")
    assert logs.read_csv(path, minimum=50).commands.shape == commands.shape
    drifting[:, 2] = np.rad2deg(drifting[:, 2])
    assert turns_57 in _error(_csv(tmp_path, commands, drifting, name="e.csv"))
    # omega_cmd in deg/s.
    turning = commands.copy()
    turning[:, 1] = np.rad2deg(turning[:, 1])
    message = _error(_csv(tmp_path, turning, measured, name="f.csv"))
    assert (
        "theta turns about 1/57 of what omega_cmd asks for: omega_cmd looks like deg/s" in message
    )
    # A log that hardly turns (straight, omega_cmd a jitter of 0.002 rad/s) tells nothing of
    # its heading's unit: read as it is, whatever its noise makes of the fit.
    for seed in (12, 140, 156):  # of 200 seeds, those a fit on the noise alone misread
        rng = np.random.default_rng(seed)
        n = 15_000
        jitter = np.column_stack([np.full(n, 20.0), rng.normal(0, 0.002, n)])
        heading = np.cumsum(np.r_[0.0, jitter[:-1, 1]]) * DT
        straight = np.column_stack([20.0 * DT * np.arange(n), np.zeros(n), heading])
        straight += rng.normal(0, [0.3, 0.3, SIGMA_THETA], (n, 3))
        read = logs.read_csv(_csv(tmp_path, jitter, straight, name="j.csv"), minimum=50)
        assert read.commands.shape == (n, 2)
    # Both in degrees, turning in place faster than 180 "rad" a sample: no radian reading fits.
    n = 200
    spin = np.column_stack([np.zeros(n), np.full(n, np.rad2deg(1.5))])
    headings = np.rad2deg(1.5 * DT * np.arange(n))
    spun = np.column_stack([np.zeros(n), np.zeros(n), headings])
    message = _error(_csv(tmp_path, spin, spun, name="g.csv"))
    assert "theta and omega_cmd look like degrees and deg/s" in message
    # t in ms: a period of 40 s, over which the robot hardly moves.
    message = _error(_csv(tmp_path, commands, measured, dt=DT * 1000, name="h.csv"))
    assert "its period is 40 s, and x, y moved" in message
    assert "t looks like milliseconds" in message
    # v_cmd and omega_cmd swapped.
    swapped = _csv(tmp_path, commands[:, ::-1], measured, name="i.csv")
    assert "or its column is omega_cmd's" in _error(swapped)
    # A wrong header.
    (tmp_path / "header.csv").write_text("t,v,w,x,y,theta\n0,0,0,0,0,0\n")
    assert "line 1" in _error(tmp_path / "header.csv")
    # The good log reads.
    assert logs.read_csv(path, minimum=50).commands.shape == commands.shape


def test_plan_stays_within_the_wheel_budget_and_holds_both_squares():
    commands = plan.plan_commands(BASE, DT, 2.0, seed=1)
    assert commands.shape == (round(120 / DT), 2)
    rims = np.abs(commands[:, 0]) + float(BASE.half_track) * np.abs(commands[:, 1])
    assert np.max(rims) <= float(BASE.v_max)
    turns = commands[(commands[:, 0] == 0) & (commands[:, 1] != 0), 1]
    # Eight quarter turns each way: 2π counter-clockwise and 2π clockwise.
    assert np.sum(turns[turns > 0]) * DT == pytest.approx(2 * np.pi, rel=1e-9)
    assert np.sum(turns[turns < 0]) * DT == pytest.approx(-2 * np.pi, rel=1e-9)


def test_an_identified_robot_equal_to_its_base_runs_the_nominal_loop():
    """Scales of 1, the base's half-track, no latency or noise: the plain rollout's poses."""
    from wmr_jax._src.identify.closed_loop import identified_rollout
    from wmr_jax._src.sim.rollout import rollout

    identified = {
        "robot": {"half_track": float(BASE.half_track), "speed_gain": float(BASE.speed_gain)},
        "wheel_scale": {"left": 1.0, "right": 1.0},
        "latency_samples": 0,
        "noise": {"sigma_xy": 0.3, "sigma_theta": 0.01},
    }
    ref, init = [30.0, 20.0, 1.0], [0.0, 0.0, 0.0]
    traj = identified_rollout(
        ref, Gains(), controller=SHIM_SUNG, init=init, dt=0.033, steps=100, velocity="ideal",
        base=BASE, identified=identified, noise=False,
    )  # fmt: skip
    with jax.enable_x64(True):
        nominal = rollout(ref, Gains(), init=init, dt=0.033, steps=100, robot=BASE)
    np.testing.assert_allclose(traj.poses, np.asarray(nominal.poses), atol=1e-9)
    # A wider true track turns less than the base believes: the run differs.
    identified["robot"]["half_track"] *= 1.05
    wider = identified_rollout(
        ref, Gains(), controller=SHIM_SUNG, init=init, dt=0.033, steps=100, velocity="ideal",
        base=BASE, identified=identified, noise=False,
    )  # fmt: skip
    assert np.max(np.abs(wider.poses - traj.poses)) > 1e-3


def test_an_identified_json_reads_as_its_true_robot(tmp_path):
    """Other commands' --robot reads identify's output as the identified robot, with a note."""
    import json

    from wmr_jax._src.model.robots import read_robot

    content = {
        "robot": {"half_track": 17.2, "speed_gain": 64.0, "v_max": 120.0},
        "wheel_scale": {"left": 1.01, "right": 0.99},
        "latency_samples": 1,
    }
    path = tmp_path / "identified.json"
    path.write_text(json.dumps(content))
    found = read_robot(str(path))
    assert (found.robot.half_track, found.robot.speed_gain) == (17.2, 64.0)
    assert "simulate, evaluate and robustness only" in found.note


def test_the_printed_table_gives_the_heading_noise_in_degrees_as_the_flags_take_it():
    from wmr_jax._src.identify.result import table

    base = {"half_track": 17.0, "speed_gain": 60.0}
    content = {
        "ci95": {
            "wheel_scale_left": [0.99, 1.01],
            "wheel_scale_right": [0.98, 1.0],
            "half_track": [17.1, 17.3],
            "speed_gain": [63.0, 65.0],
            "sigma_xy": [0.29, 0.31],
            "sigma_theta": [math.radians(0.45), math.radians(0.55)],
        },
        "base_robot": base,
        "robot": {"half_track": 17.2, "speed_gain": 64.0},
        "wheel_scale": {"left": 1.0, "right": 0.99},
        "noise": {"sigma_xy": 0.3, "sigma_theta": math.radians(0.5)},
        "latency_samples": 2,
        "ros": {"wheel_separation_multiplier": 17.2 / 17.0},
    }
    rows = {line[:20].strip(): line[20:].split() for line in table(content).splitlines()}
    assert rows["sigma_theta (deg)"] == ["0.5", "[0.45,", "0.55]"]
    assert rows["sigma_xy (cm)"] == ["0.3", "[0.29,", "0.31]"]
    assert rows["half-track (cm)"] == ["17.2", "[17.1,", "17.3]", "17"]


def test_cli_plan_and_a_bad_log(tmp_path, capsys, good, monkeypatch):
    from wmr_jax._src.cli import main as cli
    from wmr_jax._src.cli.main import main

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once

    out = tmp_path / "drive.csv"
    assert main(["identify", "--plan", str(out), "--minutes", "0.5", "--plan-dt", "0.05"]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "t,v_cmd,omega_cmd" and len(lines) == 1 + 600
    # Its folder is made; a period of seconds is warned of as milliseconds meant.
    deep = tmp_path / "new" / "sub" / "drive.csv"
    capsys.readouterr()
    assert main(["identify", "--plan", str(deep), "--minutes", "0.55", "--plan-dt", "33"]) == 0
    assert len(deep.read_text().splitlines()) == 1 + 1
    warned = "wmr-jax: warning: --plan-dt 33 is read in s; a value in milliseconds needs /1000"
    assert warned in capsys.readouterr().err
    commands, measured = good
    # A flag of the other mode is refused, not ignored.
    log = str(_csv(tmp_path, commands, measured))
    refused = {
        "--log": ["--plan", str(out), "--log", log],
        "--dt": ["--plan", str(out), "--dt", "0.04"],
        "--minutes": ["--log", log, "--out", str(tmp_path / "id"), "--minutes", "3"],
        "--seed": ["--log", log, "--out", str(tmp_path / "id"), "--seed", "4"],
        "--cmd-topic": ["--log", log, "--out", str(tmp_path / "id"), "--cmd-topic", "/cmd_vel"],
    }
    capsys.readouterr()
    for flag, argv in refused.items():
        assert main(["identify", *argv]) == 2, flag
        err = capsys.readouterr().err
        assert err.startswith(f"wmr-jax: error: {flag} is not allowed "), err
    assert not (tmp_path / "id").exists()
    metres = measured.copy()
    metres[:, :2] /= 100
    path = _csv(tmp_path, commands, metres, name="metres.csv")
    capsys.readouterr()
    assert main(["identify", "--log", str(path), "--out", str(tmp_path / "id")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("wmr-jax: error:") and "metres" in err and "\n" not in err
    # Wholly in metres: poses and commands agree, but both are 100 times small.
    slow = commands.copy()
    slow[:, 0] /= 100
    path = _csv(tmp_path, slow, metres, name="all_metres.csv")
    assert main(["identify", "--log", str(path), "--out", str(tmp_path / "id")]) == 2
    err = capsys.readouterr().err.strip()
    fastest = np.max(np.abs(slow[:, 0]))
    assert err == (
        f"wmr-jax: error: --log {path}: its fastest v_cmd is {fastest:.3g} cm/s, under 2 % of "
        "V_max of the robot paper (125 cm/s): the log looks like m/s and metres; allowed: v_cmd "
        "in cm/s and x, y in cm (multiply by 100), or --robot naming the slower robot it drove"
    )


def _identified_file(tmp_path, wheels, latency, noise):
    """An identified.json of the paper robot with these wheel scales, latency and noise."""
    import json

    from wmr_jax._src.model.robots import robot_json

    identified = {
        "robot": {"half_track": float(BASE.half_track), "speed_gain": float(BASE.speed_gain)},
        "base_robot": robot_json(BASE),
        "wheel_scale": {"left": wheels[0], "right": wheels[1]},
        "latency_samples": latency,
        "noise": {"sigma_xy": noise[0], "sigma_theta": noise[1]},
    }
    path = tmp_path / "identified.json"
    path.write_text(json.dumps(identified))
    return identified, path


def test_evaluate_on_an_identified_robot_runs_each_reference_as_simulate_does(tmp_path, capsys):
    """Latency 2 and 2 % wheel mismatch: per-reference arrival as identified_rollout's and as
    the disturbed loop's with the same wheel factors and latency (the models coincide there)."""
    import json

    from wmr_jax._src.cli.main import main
    from wmr_jax._src.identify.closed_loop import identified_rollout
    from wmr_jax._src.sim import metrics
    from wmr_jax._src.sim.poses import horizon_steps
    from wmr_jax._src.sim.rollout import DEFAULT_DT
    from wmr_jax._src.sim.sensing.disturbances import Disturbance
    from wmr_jax._src.sim.sensing.loop import disturbed_metrics

    identified, path = _identified_file(tmp_path, (1.02, 0.98), 2, (0.0, 0.0))
    refs = np.array([[40.0, 30.0, 1.0], [-30.0, 20.0, -2.0], [10.0, -50.0, 0.5]])
    np.save(tmp_path / "refs.npy", refs)
    fields = {"kr": 120.0, "k_theta": 10.0, "phi_m": math.radians(70)}
    gains = Gains(**fields)
    (tmp_path / "gains.json").write_text(json.dumps(fields))
    args = ["evaluate", "--gains", str(tmp_path / "gains.json")]
    args += ["--refs", str(tmp_path / "refs.npy"), "--robot", str(path), "--horizon", "6"]
    args += ["--json", str(tmp_path / "out.json")]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "runs on the robot identified in" in printed and "believes its base" in printed
    # Its wheels are the fitted scales (1.02, 0.98), not a ± bound drawn per run.
    assert "| wheel scales | the identified ones (up to 2 % off the model) |" in printed
    assert "wheel-radius mismatch |" not in printed
    got = json.loads((tmp_path / "out.json").read_text())
    assert got["condition"] == "identified"
    arrival = [np.inf if r["arrival_s"] is None else r["arrival_s"] for r in got["per_reference"]]
    steps = horizon_steps(DEFAULT_DT, 6.0)
    expected = []
    for ref in refs:
        traj = identified_rollout(
            ref, gains, controller=SHIM_SUNG, init=[0.0, 0.0, 0.0], dt=DEFAULT_DT, steps=steps,
            velocity="ideal", base=BASE, identified=identified, noise=False,
        )  # fmt: skip
        expected.append(float(metrics.arrival_time(traj, ref, dt=DEFAULT_DT)))
    assert np.isfinite(expected).all()
    np.testing.assert_allclose(arrival, expected, atol=1e-9)
    spec = Disturbance(
        refs, np.zeros((3, steps, 3)), np.tile([1.02, 0.98, 1.0], (3, 1)), np.float64(2.0)
    )
    m = disturbed_metrics(spec, gains, robot=BASE)
    np.testing.assert_allclose(arrival, m.arrival, atol=1e-9)
    # Without the latency and mismatch the arrivals move: the identified robot acted.
    plain = disturbed_metrics(spec._replace(mismatch=np.ones((3, 3)), delay=np.float64(0)), gains,
                              robot=BASE)  # fmt: skip
    assert np.max(np.abs(plain.arrival - np.asarray(arrival))) > 1e-3
    assert main(args + ["--condition", "noise"]) == 2


def test_evaluate_takes_gains_tuned_for_the_identified_robot():
    """tune --robot identified.json records the fitted robot; evaluate runs them on the base."""
    from wmr_jax._src.identify.closed_loop import tuned_for_identified
    from wmr_jax._src.model.robots import robot_json

    content = {
        "robot": {**robot_json(BASE), "half_track": float(BASE.half_track) * 1.04},
        "base_robot": robot_json(BASE),
    }
    fitted = BASE.replace(half_track=float(BASE.half_track) * 1.04)
    assert tuned_for_identified(fitted, content)
    assert not tuned_for_identified(BASE.replace(half_track=3.0), content)
    assert not tuned_for_identified(None, content)


def test_robustness_runs_the_gain_sets_on_an_identified_robot(tmp_path, capsys, monkeypatch):
    """Wheel scales 1.02 / 0.98 and latency 2 without tracker noise (the identified robot's
    wheel-loop gain plays no part in the ideal loop): each set's arrivals are those of the
    disturbed loop with the same wheel factors and latency, the controller believing the base;
    a file tuned for the identified robot runs there; no Monte Carlo, no noise curve."""
    import json

    from wmr_jax._src.cli.main import main
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.sim.poses import horizon_steps
    from wmr_jax._src.sim.rollout import DEFAULT_DT
    from wmr_jax._src.sim.sensing.disturbances import Disturbance
    from wmr_jax._src.sim.sensing.loop import disturbed_metrics
    from wmr_jax._src.studies.robustness import study_horizon
    from wmr_jax._src.tuning import evaluation
    from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
    from wmr_jax._src.tuning.saved import tuned_json

    monkeypatch.setattr(evaluation, "EVAL_POSES", 4)
    fitted = BASE.replace(speed_gain=float(BASE.speed_gain) * 1.3)
    content = {
        "robot": robot_json(fitted),
        "base_robot": robot_json(BASE),
        "wheel_scale": {"left": 1.02, "right": 0.98},
        "latency_samples": 2,
        "noise": {"sigma_xy": 0.0, "sigma_theta": 0.0},
    }
    path = tmp_path / "identified.json"
    path.write_text(json.dumps(content))
    tuned = Gains(kr=100.0, k_theta=12.0, phi_m=math.radians(60))
    gains_file = tmp_path / "tuned_gains.json"
    gains_file.write_text(json.dumps(tuned_json(tuned, robot=fitted, tuning="nominal")))
    out = tmp_path / "out"
    args = ["robustness", "--out", str(out), "--robot", str(path), "--controller", "shim-sung"]
    assert main(args + ["--nominal-gains", str(gains_file)]) == 0
    assert "believes its base robot" in capsys.readouterr().out
    assert not (out / "robustness.json").exists()
    rows = json.loads((out / "identified_conditions.json").read_text())["rows"]
    assert {r["condition"] for r in rows} == {
        "identified robot", "identified robot, no tracker noise", "base robot"
    }  # fmt: skip
    refs = np.asarray(evaluation.held_out_poses(4, evaluation.EVAL_SEED))
    steps = horizon_steps(DEFAULT_DT, study_horizon(BASE))
    for label, params in (("paper", paper_feasible_gains(BASE)), ("nominal-tuned", tuned)):
        for condition, factors, delay in (
            ("identified robot", [1.02, 0.98, 1.0], 2.0),
            ("base robot", [1.0, 1.0, 1.0], 0.0),
        ):
            spec = Disturbance(
                refs, np.zeros((4, steps, 3)), np.tile(factors, (4, 1)), np.float64(delay)
            )
            m = disturbed_metrics(spec, params, robot=BASE)
            (row,) = [
                r for r in rows if r["condition"] == condition and r["gains"].startswith(label)
            ]
            assert row["runs"] == 4 and row["success"] == pytest.approx(float(m.success.mean()))
            arrived = m.arrival[m.success]
            expected = float(arrived.mean()) if arrived.size else math.inf
            assert row["mean arrival s"] == pytest.approx(expected, abs=1e-9)
    # Latency 2 and 2 % between the wheels slow the paper's gains down: the robot acted.
    slow = {r["condition"]: r["mean arrival s"] for r in rows if r["gains"].startswith("paper")}
    assert slow["identified robot"] != pytest.approx(slow["base robot"], abs=1e-3)
    assert main(args + ["--noise-curve"]) == 2


def test_simulate_on_an_identified_robot_warns_as_a_rollout_and_times_no_region(
    tmp_path, capsys, monkeypatch
):

    from wmr_jax._src.cli import main as cli

    _, path = _identified_file(tmp_path, (1.0, 1.0), 0, (0.1, 0.01))
    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    # The default gains are Fig. 7's, beyond the paper robot's wheel bound.
    assert cli.main(["simulate", "--robot", str(path), "--ref", "30", "30", "0"]) == 0
    out, err = capsys.readouterr()
    assert "warning: k_r + L*k_theta = 138.5 cm/s exceeds v_max = 125 cm/s" in err
    # The law sees the tracker's noisy poses: no true region to time, and no zeros shown.
    assert "time per region: not timed (the law sees the tracker's noisy poses)" in out
    assert "R0=" not in out
    assert cli.main(["simulate", "--robot", str(path), "--ref", "30", "30", "0", "--dt", "-1"]) == 2
    assert "--dt '-1' is not allowed" in capsys.readouterr().err


def test_a_latency_identified_at_another_period_is_warned_of(tmp_path, capsys, monkeypatch):
    """Latency counts samples of the log's period: at another period it lasts another time."""
    import json
    import warnings

    from wmr_jax._src.cli import main as cli
    from wmr_jax._src.identify.closed_loop import read_identified

    identified, path = _identified_file(tmp_path, (1.0, 1.0), 2, (0.1, 0.01))
    path.write_text(json.dumps({**identified, "dt": 0.04}))
    monkeypatch.setattr(cli, "_shown_warnings", set())
    argv = ["simulate", "--robot", str(path), "--ref", "30", "30", "0", "--steps", "5"]
    assert cli.main(argv) == 0
    assert (
        f"wmr-jax: warning: --robot {path} was identified from logs at a period of 0.04 s and "
        "these runs step at 0.033 s: its latency of 2 samples lasts 66 ms here against 80 ms "
        "in the logs"
    ) in capsys.readouterr().err
    assert cli.main([*argv, "--dt", "0.04"]) == 0  # at the logs' period: nothing to say
    assert "identified from logs" not in capsys.readouterr().err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_identified(path, dt=0.04)
        path.write_text(json.dumps({**identified, "dt": 0.0333}))  # a 30 Hz tracker's
        read_identified(path)  # 0.0333 and 0.033 s: one period, within 2 %
        path.write_text(json.dumps({**identified, "dt": 0.04, "latency_samples": 0}))
        read_identified(path)  # no latency: the period changes nothing
    # At simulate --dt 0.02 the advice names that period.
    path.write_text(json.dumps({**identified, "dt": 0.04}))
    with pytest.warns(UserWarning, match=r"\(log at 0.02 s: identify --plan --plan-dt 0.02;"):
        read_identified(path, dt=0.02)
    for bad in ("0.04", float("nan"), float("inf"), 0, -0.04, True):
        path.write_text(json.dumps({**identified, "dt": bad}))
        with pytest.raises(ValueError, match=r": dt = .* is not allowed; allowed: the logs' pe"):
            read_identified(path)
    # The latency: a whole number of samples up to model.MAX_LATENCY; the keys identify writes.
    for latency in (model.MAX_LATENCY + 1, -1, 2.0, True):
        path.write_text(json.dumps({**identified, "latency_samples": latency}))
        with pytest.raises(ValueError, match=rf"latency_samples = {latency!r} is not allowed; "):
            read_identified(path)
    path.write_text(json.dumps({**identified, "latency_samples": model.MAX_LATENCY}))
    assert read_identified(path, dt=0.033)[1]["latency_samples"] == model.MAX_LATENCY
    path.write_text(json.dumps({k: v for k, v in identified.items() if k != "noise"}))
    with pytest.raises(ValueError, match=r"lacks noise; allowed: identify's output$"):
        read_identified(path)
    # Every number a run reads, checked in the file before any run, by its dotted name.
    for block, name, bad, allowed in (
        ("wheel_scale", "left", 0.0, "> 0"),
        ("wheel_scale", "right", "1", "> 0"),
        ("robot", "half_track", -8.0, "> 0"),
        ("robot", "speed_gain", float("inf"), "> 0"),
        ("noise", "sigma_xy", -0.1, ">= 0"),
        ("noise", "sigma_theta", None, ">= 0"),
    ):
        path.write_text(json.dumps({**identified, block: {**identified[block], name: bad}}))
        with pytest.raises(ValueError) as info:
            read_identified(path)
        assert str(info.value) == (
            f"--robot {path}: {block}.{name} = {bad!r} is not allowed; allowed: a finite "
            f"number {allowed}"
        )
    path.write_text(json.dumps({**identified, "noise": {**identified["noise"], "sigma_xy": 0}}))
    assert read_identified(path)[1]["noise"]["sigma_xy"] == 0  # no tracker noise: allowed
    path.write_text(json.dumps({**identified, "base_robot": {"half_track": -1}}))
    with pytest.raises(ValueError, match=r": base_robot: half_track = -1 is not allowed"):
        read_identified(path)
    # identify --plan plans at the period the commands run at, unless told otherwise.
    plan = tmp_path / "drive.csv"
    assert cli.main(["identify", "--plan", str(plan), "--minutes", "0.05"]) == 0
    times = np.loadtxt(plan, delimiter=",", skiprows=1)[:, 0]
    np.testing.assert_allclose(np.diff(times), 0.033, atol=1e-6)


def test_the_metres_check_leaves_turning_logs_with_stray_speeds_alone():
    from wmr_jax._src.cli.identify import _check_speed_unit

    commands = np.zeros((200, 2))
    commands[:, 1] = 1.0  # turning in place
    commands[:10, 0] = 0.5  # a joystick's dead band: 5 % of the samples, 0.5 cm/s
    log = logs.Log(DT, commands, np.zeros((200, 3)), "spin.csv")
    _check_speed_unit(log, BASE, "paper")  # not refused
    commands[:30, 0] = 0.5  # 15 % of the samples, never above 0.5 cm/s: metres
    with pytest.raises(ValueError, match="spin.csv: its fastest v_cmd is 0.5 cm/s"):
        _check_speed_unit(log._replace(commands=commands), BASE, "paper")


def test_the_example_log_identifies_its_truth_within_every_interval(tmp_path, capsys):
    """The README's ``identify`` line: docs/data/example_log.csv, written by
    ``experiments/identified_vs_base.py --log-only --minutes 1``, holds its true robot
    in each printed 95 % interval, and the latency exactly."""
    import importlib.util
    import json
    from pathlib import Path

    from wmr_jax._src.cli.main import main

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location(
        "identified_vs_base", root / "experiments" / "identified_vs_base.py"
    )
    experiment = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(experiment)
    log = root / "docs" / "data" / "example_log.csv"
    assert main(["identify", "--log", str(log), "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    found = json.loads((tmp_path / "identified.json").read_text())
    base = load_robot("paper")
    truth = {
        "wheel_scale_left": experiment.SCALE[0],
        "wheel_scale_right": experiment.SCALE[1],
        "half_track": float(base.half_track) * experiment.TRACK,
        "speed_gain": float(base.speed_gain),
        "sigma_xy": experiment.SIGMA_XY,
        "sigma_theta": experiment.SIGMA_THETA,
    }
    for name, value in truth.items():
        low, high = found["ci95"][name]
        assert low <= value <= high, (name, low, value, high)
    assert found["latency_samples"] == experiment.LATENCY
    assert found["dt"] == pytest.approx(0.033)  # the period the commands run at: no warning
