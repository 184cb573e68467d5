"""The benchmark command on tiny sizes (no timing is asserted), and its NumPy baseline."""

import argparse
import json

import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import bench


def test_numpy_baseline_is_the_same_closed_loop():
    """The vectorised NumPy baseline simulates what final_poses does (float64)."""
    refs = random_refs(np.random.default_rng(0), 50)
    gains = w.Gains(kr=60.0)
    got = bench.numpy_final_poses(refs, gains, steps=120)
    want = np.asarray(w.final_poses(refs, gains, steps=120))
    assert got.dtype == np.float64
    # Angles and atan2 against cosines: float64 rounding, as in test_reference.
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert bench.numpy_final_poses(refs.astype(np.float32), gains, steps=3).dtype == np.float32


def test_bench_command_writes_table_and_json(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    bench.configure_parser(parser)
    out = tmp_path / "bench.json"
    args = parser.parse_args(
        [
            "--sizes", "8", "16",
            "--steps", "4",
            "--repeats", "1",
            "--reference-poses", "2",
            "--dtype", "float64",  # the test session runs with x64 on
            "--cpu-devices", "1",  # leave the session's devices alone
            "--cases", "final_poses", "grad_final_pose_loss", "numpy_batch", "scalar_reference",
            "--json", str(out),
        ]
    )  # fmt: skip
    assert bench.run_cli(args) == 0
    table = capsys.readouterr().out
    assert "| final_poses | 16 |" in table and "scalar_reference" in table
    assert "jax " in table
    result = json.loads(out.read_text())
    assert result["environment"]["jax"] and result["environment"]["device"]
    cases = {(row["case"], row["n"]) for row in result["rows"]}
    assert {("final_poses", 8), ("numpy_batch", 16), ("scalar_reference", 2)} <= cases
    assert ("grad_final_pose_loss", 16) in cases
    for row in result["rows"]:
        assert row["robot_steps_per_s"] > 0 and row["run_s"] > 0
    ratios = result["ratios"]["N=16"]
    assert ratios["vs_numpy_batch"] > 0 and ratios["vs_scalar_reference"] > 0
    assert ratios["grad_final_pose_loss_over_forward"] > 0


def test_bench_rejects_bad_config():
    with pytest.raises(ValueError, match="sizes"):
        bench.run_benchmark(bench.BenchConfig(sizes=(0,)))
    with pytest.raises(ValueError, match="cases"):
        bench.run_benchmark(bench.BenchConfig(cases=("warp_drive",)))
    with pytest.raises(ValueError, match="float32"):  # x64 is on in the test session
        bench.run_benchmark(bench.BenchConfig(sizes=(4,), dtype="float32"))
