"""The GIF of a batch of robots: written atomically, readable, with the expected frames."""

import argparse

import numpy as np
import pytest
from PIL import Image

from wmr_jax import animation


def test_gif_smoke(tmp_path):
    path = animation.animate(
        tmp_path / "robots.gif", n_robots=3, steps=20, stride=5, controller="aicardi"
    )
    data = path.read_bytes()
    assert data[:6] in (b"GIF87a", b"GIF89a")
    with Image.open(path) as image:
        assert image.n_frames == 5  # samples 0, 5, 10, 15 and the last, 20
    assert [p.name for p in tmp_path.iterdir()] == ["robots.gif"]  # no temporary left


def test_write_gif_checks_shapes(tmp_path):
    with pytest.raises(ValueError, match="allowed: poses"):
        animation.write_gif(tmp_path / "x.gif", np.zeros((2, 5, 3)), np.zeros((3, 3)))
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "movie.mp4"], "--out = 'movie.mp4'"),
        (["--out", "a.gif", "--controller", "nope"], "--controller = 'nope'"),
        (["--out", "a.gif", "--robots", "0"], "--robots = 0"),
        (["--out", "a.gif", "--seconds", "-1"], "--seconds = -1.0"),
        (["--out", "a.gif", "--velocity", "warp"], "--velocity = 'warp'"),
    ],
)
def test_cli_bad_values(argv, message):
    parser = argparse.ArgumentParser()
    animation.configure_parser(parser)
    args = parser.parse_args(argv)
    with pytest.raises(ValueError) as info:
        args.func(args)
    assert message in str(info.value) and "\n" not in str(info.value)
