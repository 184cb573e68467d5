"""The GIF of a batch of robots: written atomically, readable, with the expected frames."""

import numpy as np
import pytest
from PIL import Image

from wmr_jax.cli import main
from wmr_jax.report import animate, write_gif


def _frames(path):
    assert path.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    with Image.open(path) as image:
        return image.n_frames


def test_animate_command_and_function(tmp_path, capsys):
    gif = tmp_path / "robots.gif"
    argv = ["animate", "--out", str(gif), "--robots", "3", "--seconds", "0.66"]
    assert main([*argv, "--controller", "aicardi"]) == 0
    assert str(gif) in capsys.readouterr().out
    assert _frames(gif) == 11  # 0.66 s = 20 periods; every 2nd sample, 0 to 20
    assert [p.name for p in tmp_path.iterdir()] == ["robots.gif"]  # no temporary left

    # The same runs (3 random poses, seed 0, 20 periods) with 5 samples per frame.
    path = animate(tmp_path / "again.gif", n_robots=3, steps=20, stride=5, controller="aicardi")
    assert _frames(path) == 5  # samples 0, 5, 10, 15 and the last, 20


def test_write_gif_checks_shapes(tmp_path):
    with pytest.raises(ValueError, match="allowed: poses"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 5, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="stride = 0"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 5, 3)), np.zeros((2, 3)), stride=0)
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "movie.mp4"], "--out 'movie.mp4'"),
        (["--out", "a.gif", "--controller", "nope"], "--controller 'nope'"),
        (["--out", "a.gif", "--robots", "0"], "--robots '0'"),
        (["--out", "a.gif", "--seed", "-1"], "--seed '-1'"),
        (["--out", "a.gif", "--seconds", "-1"], "--seconds '-1'"),
        (["--out", "a.gif", "--velocity", "warp"], "--velocity 'warp'"),
        (["--out", "a.gif", "--fps", "0"], "--fps '0'"),
    ],
)
def test_animate_command_bad_values(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["animate", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "allowed" in err[0], err
    assert list(tmp_path.iterdir()) == []
