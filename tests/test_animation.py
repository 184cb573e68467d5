"""The GIF of a batch of robots: written atomically, readable, with the expected frames."""

import numpy as np
import pytest
from PIL import Image

import wmr_jax as w
from wmr_jax.cli import main
from wmr_jax.report import write_gif


def _frames(path):
    assert path.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    with Image.open(path) as image:
        return image.n_frames


# Every GIF here shows 2 robots over 12 periods: each frame takes a while to
# draw, and the arrival marks are computed op by op, compiled once for that shape.
PERIODS = 12


def test_animate_command_and_a_gif_of_recorded_runs(tmp_path, capsys):
    gif = tmp_path / "robots.gif"
    argv = ["animate", "--out", str(gif), "--robots", "2", "--seconds", "0.396"]
    assert main([*argv, "--controller", "aicardi"]) == 0
    assert str(gif) in capsys.readouterr().out
    # 0.396 s = 12 periods; real time at 33 ms takes every 3rd sample (100 ms a frame).
    assert _frames(gif) == 5  # samples 0, 3, 6, 9, 12
    assert [p.name for p in tmp_path.iterdir()] == ["robots.gif"]  # no temporary left

    # The same runs (2 random poses, seed 0, 12 periods), recorded here and
    # drawn with 5 samples per frame.
    refs = np.asarray(w.sample_poses(0, 2), dtype=float)
    runs = w.batch_rollout(refs, steps=PERIODS, controller="aicardi")
    path = write_gif(tmp_path / "again.gif", np.asarray(runs.poses), refs, stride=5)
    assert _frames(path) == 4  # samples 0, 5, 10 and the last, 12


def test_a_frame_is_at_most_600_by_630_pixels_whatever_the_pitch(tmp_path):
    """The bound ``animate`` checks its frames' memory against, before it simulates."""
    for span, tall in (((10.0, 100.0), True), ((100.0, 10.0), False), ((50.0, 50.0), None)):
        poses = np.zeros((1, 2, 3))
        poses[0, 1, :2] = span
        path = write_gif(tmp_path / "a.gif", poses, poses[:, 1], stride=1)
        with Image.open(path) as image:
            width, height = image.size
        # A tall pitch is widened to a square, not drawn as a sliver; a wide one is lower.
        assert width == 600 and (height == 630 if tall in (True, None) else height < 630)


def _delays_ms(path):
    with Image.open(path) as image:
        delays = []
        for i in range(image.n_frames):
            image.seek(i)
            delays.append(image.info["duration"])
    return delays


@pytest.mark.parametrize(("dt", "speed"), [(0.033, 1.0), (0.01, 1.0), (0.033, 2.0)])
def test_gif_plays_in_real_time(tmp_path, dt, speed):
    """Each frame lasts the simulated time it spans (÷ speed), within 2 %."""
    poses = np.zeros((2, PERIODS + 1, 3))
    poses[:, :, 0] = np.linspace(0.0, 10.0, PERIODS + 1)
    path = write_gif(tmp_path / "t.gif", poses, np.zeros((2, 3)), dt=dt, speed=speed)
    delays = _delays_ms(path)
    n = len(delays)
    stride = PERIODS // (n - 1) if PERIODS % (n - 1) == 0 else PERIODS // (n - 2)
    assert set(delays) == {delays[0]}
    assert abs(delays[0] - 1000 * stride * dt / speed) <= 0.02 * 1000 * stride * dt / speed


def test_write_gif_checks_shapes(tmp_path):
    with pytest.raises(ValueError, match="allowed: poses"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 5, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="stride = 0"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 5, 3)), np.zeros((2, 3)), stride=0)
    with pytest.raises(ValueError, match=r"^poses of 801 samples at stride 1 makes 801 frames"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 801, 3)), np.zeros((2, 3)), stride=1)
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "movie.mp4"], "--out 'movie.mp4'"),
        (["--out", "a.gif", "--controller", "nope"], "--controller 'nope'"),
        (["--out", "a.gif", "--robots", "0"], "--robots '0'"),
        (["--out", "a.gif", "--seed", "-1"], "--seed '-1'"),
        (["--out", "a.gif", "--seconds", "-1"], "--seconds '-1'"),
        (["--out", "a.gif", "--seconds", "0.03"], "--seconds '0.03'"),  # under one period
        (["--out", "a.gif", "--seconds", "600.5"], "--seconds '600.5'"),
        (["--out", "a.gif", "--robots", "10001"], "--robots '10001'"),
        (["--out", "a.gif", "--seed", "4294967296"], "--seed '4294967296'"),
        (["--out", "a.gif", "--speed", "100.5"], "--speed '100.5'"),
        (["--out", "a.gif", "--velocity", "warp"], "--velocity 'warp'"),
        (["--out", "a.gif", "--speed", "0"], "--speed '0'"),
        (["--out", "a.gif", "--speed", "1e-5"], "speed = 1e-05"),  # no GIF can play it
        (["--out", "a.gif", "--paper", "--robots", "5"], "--robots is not allowed with --paper"),
        (["--out", "a.gif", "--paper", "--seed", "3"], "--seed is not allowed with --paper"),
        # More frames than memory should hold while the GIF is encoded (1 GiB of pixels).
        (
            ["--out", "a.gif", "--seconds", "600"],
            "--seconds 600 at --speed 1 makes 6062 frames of 600×630 pixels, 8.5 GiB held in "
            "memory while the GIF is encoded; allowed: at most 710 frames (--seconds 70.19 at "
            "the most at --speed 1)",
        ),
    ],
)
def test_animate_command_bad_values(tmp_path, monkeypatch, capsys, argv, message):
    from wmr_jax._src.sim import rollout

    def no_runs(*args, **kwargs):
        raise AssertionError("refused only after simulating")

    monkeypatch.setattr(rollout, "batch_rollout", no_runs)  # every refusal comes first
    monkeypatch.chdir(tmp_path)
    assert main(["animate", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "allowed" in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_animate_command_runs_what_its_flags_ask(tmp_path, monkeypatch):
    """The references, controller, loop, periods and playback the command hands on."""
    from types import SimpleNamespace

    from wmr_jax._src.report import animation
    from wmr_jax._src.sim import rollout

    runs, drawn = [], []

    def fake(refs, params=None, **kwargs):
        runs.append((np.asarray(refs), kwargs))
        return SimpleNamespace(poses=np.zeros((len(refs), kwargs["steps"] + 1, 3)))

    monkeypatch.setattr(rollout, "batch_rollout", fake)
    monkeypatch.setattr(animation, "write_gif", lambda path, *a, **kw: drawn.append(kw) or path)
    out = ["animate", "--out", str(tmp_path / "a.gif")]
    flags = ["--paper", "--controller", "aicardi", "--velocity", "nonideal", "--speed", "2"]
    assert main([*out, *flags, "--seconds", "1"]) == 0
    refs, kwargs = runs[-1]
    np.testing.assert_array_equal(refs, w.paper_refs())
    assert kwargs["controller"] == "aicardi" and kwargs["velocity"] == "nonideal"
    assert kwargs["steps"] == 31  # 1 s of 33 ms periods, the last one partly
    assert drawn[-1]["speed"] == 2.0
    assert drawn[-1]["title"] == "aicardi, nonideal loop: 7 robots from (0, 0, 0°)"
    # Random references: the seed's first poses; one period at the least, 600 s at the most.
    assert main([*out, "--robots", "3", "--seed", "5", "--seconds", "0.033"]) == 0
    refs, kwargs = runs[-1]
    np.testing.assert_array_equal(refs, np.asarray(w.sample_poses(5, 3), dtype=float))
    assert kwargs["steps"] == 1 and kwargs["velocity"] == "ideal"
    limits = ["--robots", "10000", "--seed", "4294967295", "--seconds", "600", "--speed", "100"]
    assert main([*out, *limits]) == 0
    assert len(runs[-1][0]) == 10_000 and runs[-1][1]["steps"] == 18_182
    assert main([*out, "--robots", "1", "--seed", "0"]) == 0 and len(runs[-1][0]) == 1
