"""The benchmark on tiny sizes (no timing is asserted), and its NumPy baseline."""

import json

import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax.cli import main


def test_numpy_baseline_is_the_same_closed_loop():
    """The vectorised NumPy baseline simulates what final_poses does (float64)."""
    refs = random_refs(0, 50)
    gains = w.Gains(kr=60.0)
    got = w.studies.numpy_final_poses(refs, gains, steps=120)
    want = np.asarray(w.final_poses(refs, gains, steps=120))
    assert got.dtype == np.float64
    # Angles and atan2 against cosines: float64 rounding, as in test_reference.
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert w.studies.numpy_final_poses(refs.astype(np.float32), gains, steps=3).dtype == np.float32


def test_bench_command_writes_table_and_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    argv = [
        "bench",
        "--sizes", "8", "16",
        "--steps", "4",
        "--repeats", "1",
        "--reference-poses", "8",  # as many as the first size: one pose sampler compiled
        "--dtype", "float64",  # the test session runs with x64 on
        "--cpu-devices", "1",
        "--cases", "final_poses", "numpy_batch", "scalar_reference",
        "--json", str(out),
    ]  # fmt: skip
    assert main(argv) == 0
    table = capsys.readouterr().out
    assert "| final_poses | 16 |" in table and "scalar_reference" in table
    assert "jax " in table and "| N | final_poses / NumPy batch |" in table
    result = json.loads(out.read_text())
    assert result["environment"]["jax"] and result["environment"]["device"]
    cases = [(row["case"], row["n"]) for row in result["rows"]]
    # Per size: final_poses, then the NumPy batch; the scalar reference once, at the end.
    assert cases == [
        ("final_poses", 8),
        ("numpy_batch", 8),
        ("final_poses", 16),
        ("numpy_batch", 16),
        ("scalar_reference", 8),
    ]
    for row in result["rows"]:
        assert row["robot_steps_per_s"] > 0 and row["run_s"] > 0
    ratios = result["ratios"]["N=16"]
    assert ratios["vs_numpy_batch"] > 0 and ratios["vs_scalar_reference"] > 0
    assert result["finished"] is True
    # Interrupted in the second size: the file keeps the first, marked unfinished.
    from wmr_jax._src.studies import bench

    rows = bench._SizeBench.rows

    def interrupted(self, *, scalar):
        if self.n == 16:
            raise KeyboardInterrupt
        return rows(self, scalar=scalar)

    out.unlink()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(bench._SizeBench, "rows", interrupted)
        assert main(argv) == 130
    assert f"wmr-jax: interrupted ({out} holds the batch sizes it finished)" in (
        capsys.readouterr().err
    )
    kept = json.loads(out.read_text())
    assert kept["finished"] is False
    assert [(row["case"], row["n"]) for row in kept["rows"]] == cases[:2]
    assert list(kept["ratios"]) == ["N=8"]
    # Interrupted in the first: no row, and no earlier run's file left looking finished.
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(bench._SizeBench, "rows", lambda self, *, scalar: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            main(argv)
    kept = json.loads(out.read_text())
    assert kept["finished"] is False and kept["rows"] == []


def test_page_faults_count_the_memory_a_call_takes_fresh_from_the_kernel():
    """A call that writes into 128 MiB of new pages faults them in; one reusing memory does not."""
    from wmr_jax._src.studies.bench_timing import time_group

    size, huge_page = 128 << 20, 2 << 20
    kept = np.ones(size // 8)
    timings = time_group(
        {
            "fresh": (lambda: np.ones(size // 8), False),  # a new mapping each call
            "reused": (lambda: kept.fill(2.0), False),
        },
        repeats=3,
    )
    # At least one fault per page, however large the kernel makes them (4 KiB or 2 MiB).
    assert timings["fresh"].page_faults >= 0.9 * size / huge_page
    assert timings["reused"].page_faults < 10


def test_both_losses_and_their_gradients_are_timed():
    """Each loss is timed with its gradient, not skipped, and their ratios are reported."""
    cases = ("final_poses", "final_poses_nonideal", "grad_final_pose_loss", "grad_tuning_loss")
    # The first size and the steps of the command above: its poses and final_poses are reused.
    config = w.studies.BenchConfig(sizes=(8,), steps=4, repeats=1, dtype="float64", cases=cases)
    result = w.studies.run_benchmark(config)
    rows = result["rows"]
    assert [row["case"] for row in rows] == [
        "final_poses",
        "final_poses_nonideal",
        "final_pose_loss",
        "jvp_final_pose_loss",
        "grad_final_pose_loss",
        "final_poses_relaxed",
        "tuning_loss",
        "jvp_tuning_loss",
        "grad_tuning_loss",
    ]
    assert all(row["robot_steps_per_s"] > 0 for row in rows)
    ratios = result["ratios"]["N=8"]
    for key in (
        "grad_final_pose_loss_over_forward",
        "grad_tuning_loss_over_forward",
        "jvp_final_pose_loss_over_forward",
        "jvp_tuning_loss_over_forward",
        "tuning_loss_over_final_poses",
        "tuning_loss_over_relaxed",
        "relaxed_over_final_poses",
        "nonideal_over_ideal",
    ):
        assert ratios[key] > 0, key
    table = w.report.bench_table(result)
    assert "non-ideal / ideal final_poses" in table
    assert "one forward-mode derivative / forward (tuning loss)" in table


def test_the_robust_loss_is_timed_with_its_gradient_and_one_jvp(monkeypatch):
    """The robust tuner's loss, the trainer's gradient of it and a jvp, with their ratios.

    On the 7 fixed gains with raw feedback: the case's plumbing is the same as
    with the default schedule and filter, at a fraction of the compile time.
    """
    from wmr_jax._src.tuning import robust

    small = robust.RobustConfig(law="fixed", estimator=None)
    monkeypatch.setattr(robust, "RobustConfig", lambda: small)
    config = w.studies.BenchConfig(
        sizes=(2,), steps=4, repeats=1, dtype="float64", cases=("grad_robust_loss",)
    )
    result = w.studies.run_benchmark(config)
    rows = result["rows"]
    assert [row["case"] for row in rows] == ["robust_loss", "jvp_robust_loss", "grad_robust_loss"]
    assert rows[0]["runs"] == 2 * 4 + 1  # four standard conditions, one non-ideal run
    assert all(row["run_s"] > 0 for row in rows)
    ratios = result["ratios"]["N=2"]
    assert ratios["grad_robust_loss_over_forward"] > 0
    assert ratios["jvp_robust_loss_over_forward"] > 0
    assert "grad / forward (robust loss)" in w.report.bench_table(result)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"sizes": (0,)}, "sizes"),
        ({"sizes": ()}, "sizes"),
        ({"repeats": 0}, "repeats"),
        ({"wait_idle": -1.0}, "wait_idle"),
        ({"cases": ("warp_drive",)}, "cases"),
        ({"dtype": "float16"}, "dtype"),
        ({"sizes": (4,), "dtype": "float32"}, "float32"),  # x64 is on in the test session
    ],
)
def test_bench_rejects_bad_config(config, message):
    with pytest.raises(ValueError, match=message):
        w.studies.run_benchmark(w.studies.BenchConfig(**config))
