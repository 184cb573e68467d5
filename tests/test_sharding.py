"""Batches sharded over several devices and several processes give the unsharded results.

JAX fixes its device count when it starts, so each scenario runs in a fresh
Python process: four CPU devices from one process (``wmr_jax.studies.use_cpu_devices(4)``
before JAX starts), in float64; and two processes on this host joined by
``jax.distributed`` with two CPU devices each, in float32.

Exact equality is expected, not approximate: every device runs the same
per-row arithmetic. Batches are sized so that each device gets a multiple of
32 rows; XLA then runs only full vector iterations on every device, as it
does for the whole batch on one (rows in a loop's scalar remainder may round
differently from those in its vector body).
"""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import wmr_jax as w

TIMEOUT_S = 240
STEPS = 30


def _env(**extra: str) -> dict:
    """This process's environment for a subprocess: its XLA flags, and ``extra``'s.

    The device count is the subprocess's own; the optimisation level and the
    emitters are this process's (tests/conftest.py), so that both compile the
    same programs and their float32 results can be compared bit for bit.
    """
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    flags = [
        flag
        for flag in os.environ.get("XLA_FLAGS", "").split()
        if flag.startswith(("--xla_backend_optimization_level", "--xla_cpu_use_fusion_emitters"))
    ]
    flags += extra.pop("XLA_FLAGS", "").split()
    return {**env, **extra, **({"XLA_FLAGS": " ".join(flags)} if flags else {})}


FOUR_DEVICES = f"""
import json, warnings
warnings.simplefilter("ignore")
import wmr_jax as w
first = w.studies.use_cpu_devices(4)  # before JAX starts: four CPU devices
import jax, numpy as np, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
report = {{"devices": [first, w.studies.use_cpu_devices(5), len(jax.devices())]}}  # 5: too late
equal = lambda a, b: bool(np.array_equal(np.asarray(a), np.asarray(b)))
rng = np.random.default_rng(3)
refs, kr = rng.uniform(-40, 40, (256, 3)), rng.uniform(40, 120, 256)

# Per-pose gains sharded with the poses, as one pytree.
batch = w.shard((refs, kr))
sharded_refs, sharded_kr = batch.array
report["n"] = [batch.n, batch.n_padded]
got = w.final_poses(sharded_refs, w.Gains(kr=sharded_kr), steps={STEPS})
want = w.final_poses(jnp.asarray(refs), w.Gains(kr=jnp.asarray(kr)), steps={STEPS})
report["final_equal"] = equal(got, want)
report["final_same_sharding"] = got.sharding == sharded_refs.sharding
traj = w.batch_rollout(sharded_refs, steps={STEPS})
report["rollout_sharded"] = all(f.sharding.spec[0] == "batch" for f in traj)
plain = w.batch_rollout(jnp.asarray(refs), steps={STEPS})
report["rollout_equal"] = all(equal(a, b) for a, b in zip(traj, plain))

# A batch that does not divide: padded with copies of the last row (to the
# shape above, so that the compiled program is reused).
odd = w.shard((refs[:254], kr[:254]))
report["odd"] = [odd.n, odd.n_padded]
padded = np.asarray(odd.array[0])
report["padding_repeats_last"] = equal(padded[254:], np.repeat(padded[253:254], 2, 0))
out = w.unpad(w.final_poses(odd.array[0], w.Gains(kr=odd.array[1]), steps={STEPS}), odd.n)
report["unpadded_shape"] = list(out.shape)
report["unpadded_equal"] = equal(out, want[:254])

# The sweep spreads each chunk over all local devices by default.
res = w.sweep(refs, w.Gains(kr=kr), steps={STEPS}, chunk_size=128)
report["sweep_final_equal"] = equal(res["final_x"], want[:, 0])
print(json.dumps(report))
"""


def test_four_devices_match_one():
    proc = subprocess.run(
        [sys.executable, "-c", FOUR_DEVICES],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    # Four devices once asked before JAX started; too late to change afterwards.
    assert report["devices"] == [4, 4, 4]
    assert report["n"] == [256, 256]
    assert report["final_equal"] and report["final_same_sharding"]
    assert report["rollout_sharded"] and report["rollout_equal"]
    assert report["odd"] == [254, 256] and report["padding_repeats_last"]
    assert report["unpadded_shape"] == [254, 3]
    # 64 rows per device, as for the whole batch: the same rows, equal.
    assert report["unpadded_equal"]
    assert report["sweep_final_equal"]


WORKER = f"""
import sys, warnings
warnings.simplefilter("ignore")
process_id, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
import jax
jax.config.update("jax_cpu_collectives_implementation", "gloo")
jax.distributed.initialize(
    coordinator_address=f"localhost:{{port}}", num_processes=2, process_id=process_id
)
import numpy as np
from jax.experimental import multihost_utils
import wmr_jax as w

refs = np.random.default_rng(5).uniform(-40, 40, (128, 3))  # the same on every process
batch = w.shard(refs)  # over the 4 devices of both processes
assert len(jax.devices()) == 4 and len(jax.local_devices()) == 2
assert not batch.array.is_fully_addressable
final = w.final_poses(batch.array, steps={STEPS})
assert final.sharding == batch.array.sharding
gathered = multihost_utils.process_allgather(final, tiled=True)[: batch.n]
np.save(out, np.asarray(gathered))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_on_localhost(tmp_path: Path):
    """jax.distributed with CPU (gloo) collectives: one global batch over two processes."""
    port = _free_port()
    env = _env(XLA_FLAGS="--xla_force_host_platform_device_count=2")
    outs = [tmp_path / f"final{i}.npy" for i in range(2)]
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WORKER, str(i), str(port), str(outs[i])],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for i in range(2)
    ]
    logs = []
    try:
        for p in procs:
            _, err = p.communicate(timeout=TIMEOUT_S)
            logs.append(err)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    if any(p.returncode for p in procs) and any("gloo" in e.lower() for e in logs):
        unsupported = [e for e in logs if "not" in e.lower() and "gloo" in e.lower()]
        if unsupported:
            pytest.skip("this jaxlib has no gloo CPU collectives: " + unsupported[0][-300:])
    assert all(p.returncode == 0 for p in procs), "\n".join(e[-2000:] for e in logs)
    refs = np.random.default_rng(5).uniform(-40, 40, (128, 3))
    with jax.enable_x64(False):
        want = np.asarray(w.final_poses(refs.astype(np.float32), steps=STEPS))
    for out in outs:
        np.testing.assert_array_equal(np.load(out), want)


def test_shard_validates_its_input():
    with pytest.raises(ValueError, match="leading lengths"):
        w.shard((np.zeros((4, 3)), np.zeros(5)))
    with pytest.raises(ValueError, match="leading lengths"):
        w.shard(np.float64(1.0))
    with pytest.raises(ValueError, match="at least one device"):
        w.shard(np.zeros((4, 3)), devices=[])
    with pytest.raises(ValueError, match="count = 0"):
        w.studies.use_cpu_devices(0)
    one = w.shard(np.zeros((5, 3)), devices=jax.devices()[:1])  # one device: no padding
    assert one.n == one.n_padded == 5
    np.testing.assert_array_equal(w.unpad(np.arange(8), 5), np.arange(5))
    for n in (-1, 9, True):
        with pytest.raises(ValueError, match=f"n = {n!r} is not allowed"):
            w.unpad(np.arange(8), n)
    rows = [[30.0, 30.0, 0.0], [20.0, -10.0, 1.0]]
    assert w.shard(rows, devices=jax.devices()[:1]).n == 2  # a list of rows is an array
    # A list of poses could be two rows or two batches of 3: it is refused, not guessed.
    with pytest.raises(ValueError, match="list of 2 one-dimensional arrays: rows of one batch"):
        w.shard([np.zeros(3), np.zeros(3)])
    pair = w.shard([np.zeros((4, 3)), np.ones((4, 2))], devices=jax.devices()[:1])
    assert pair.n == 4 and [a.shape for a in pair.array] == [(4, 3), (4, 2)]  # two batches
    with pytest.raises(ValueError, match="rows of different lengths"):
        w.shard([[1.0, 2.0, 3.0], [1.0, 2.0]])
    with pytest.raises(ValueError, match=r"\[1, 2\] = nan\) is not allowed; allowed: finite"):
        w.shard([[1.0, 2.0, 3.0], [1.0, 2.0, np.nan]])
    with pytest.raises(ValueError, match="result has no rows"):
        w.unpad(np.zeros((0, 3)), 1)
    with pytest.raises(ValueError, match="allowed: JAX devices"):
        w.shard(np.zeros((4, 3)), devices=[0])
    with pytest.raises(ValueError, match="names a device twice"):
        w.shard(np.zeros((4, 3)), devices=jax.devices()[:1] * 2)
    with pytest.raises(ValueError, match="allowed: numbers"):
        w.shard(np.array(["a", "b"]))
