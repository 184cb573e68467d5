"""Batches sharded over several devices and several processes give the unsharded results.

JAX fixes its device count when it starts, so each scenario runs in a fresh
Python process: four CPU devices from one process
(``--xla_force_host_platform_device_count=4``), and two processes on this
host joined by ``jax.distributed`` with two CPU devices each.

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
import textwrap
from pathlib import Path

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import sharding

TIMEOUT_S = 240


def _run(script: str, *, devices: int, env: dict | None = None) -> subprocess.CompletedProcess:
    full_env = dict(os.environ)
    full_env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    full_env.update(env or {})
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        env=full_env,
        timeout=TIMEOUT_S,
    )


FOUR_DEVICES = r"""
import json, warnings
warnings.simplefilter("ignore")
import jax
import numpy as np, jax.numpy as jnp
import wmr_jax as w
from wmr_jax import sharding

x64 = {x64}
jax.config.update("jax_enable_x64", x64)
dtype = jnp.float64 if x64 else jnp.float32
report = {{"devices": len(jax.devices())}}
rng = np.random.default_rng(3)
refs = rng.uniform(-40, 40, (256, 3))
kr = rng.uniform(40, 120, 256)

batch = sharding.shard(refs)
report["n"], report["n_padded"] = batch.n, batch.n_padded
plain = jnp.asarray(refs, dtype)
final = w.final_poses(batch.array, steps=60)
report["final_same_sharding"] = final.sharding == batch.array.sharding
report["final_equal"] = bool(np.array_equal(np.asarray(final), np.asarray(
    w.final_poses(plain, steps=60))))
traj = w.batch_rollout(batch.array, steps=60)
report["rollout_sharded"] = all(f.sharding.spec[0] == "batch" for f in traj)
report["rollout_equal"] = all(
    bool(np.array_equal(np.asarray(a), np.asarray(b)))
    for a, b in zip(traj, w.batch_rollout(plain, steps=60)))

# Per-pose gains sharded with the poses, one pytree.
both = sharding.shard((refs, kr))
sharded_refs, sharded_kr = both.array
got = w.final_poses(sharded_refs, w.Gains(kr=sharded_kr), steps=60)
want = w.final_poses(plain, w.Gains(kr=jnp.asarray(kr, dtype)), steps=60)
report["gains_equal"] = bool(np.array_equal(np.asarray(got), np.asarray(want)))
report["gains_same_sharding"] = got.sharding == sharded_refs.sharding

# A batch that does not divide: padded with copies of the last row.
odd = sharding.shard(refs[:10])
report["odd"] = [odd.n, odd.n_padded]
padded = np.asarray(odd.array)
report["padding_repeats_last"] = bool(np.array_equal(padded[10:], np.repeat(padded[9:10], 2, 0)))
out = sharding.unpad(w.final_poses(odd.array, steps=20), odd.n)
report["unpadded_shape"] = list(out.shape)
report["unpadded_close"] = float(np.abs(np.asarray(out) - np.asarray(
    w.final_poses(jnp.asarray(refs[:10], dtype), steps=20))).max())

# The sweep spreads each chunk over all local devices by default.
from wmr_jax import sweep
res = sweep.sweep(refs, steps=60, chunk_size=128)
report["sweep_final_equal"] = bool(np.array_equal(res["final_x"], np.asarray(final[:, 0])))
print(json.dumps(report))
"""


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_four_devices_match_one(dtype):
    script = FOUR_DEVICES.format(x64=dtype == "float64")
    proc = _run(script, devices=4)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["devices"] == 4
    assert report["n"] == report["n_padded"] == 256
    assert report["final_same_sharding"] and report["final_equal"]
    assert report["rollout_sharded"] and report["rollout_equal"]
    assert report["gains_equal"] and report["gains_same_sharding"]
    assert report["odd"] == [10, 12] and report["padding_repeats_last"]
    assert report["unpadded_shape"] == [10, 3]
    # 10 rows over 4 devices: some fall in a loop's scalar remainder, so a
    # float32 ulp or two (a few 1e-6 cm) rather than exact equality.
    assert report["unpadded_close"] < 1e-4
    assert report["sweep_final_equal"]


WORKER = r"""
import sys, warnings
warnings.simplefilter("ignore")
process_id, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
import jax
jax.config.update("jax_cpu_collectives_implementation", "gloo")
jax.distributed.initialize(
    coordinator_address=f"localhost:{port}", num_processes=2, process_id=process_id
)
import numpy as np
from jax.experimental import multihost_utils
import wmr_jax as w
from wmr_jax import sharding

refs = np.random.default_rng(5).uniform(-40, 40, (256, 3))  # the same on every process
batch = sharding.shard(refs)  # over the 4 devices of both processes
assert len(jax.devices()) == 4 and len(jax.local_devices()) == 2
assert not batch.array.is_fully_addressable
final = w.final_poses(batch.array, steps=60)
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
    env = dict(os.environ)
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
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
    refs = np.random.default_rng(5).uniform(-40, 40, (256, 3))
    import jax

    with jax.enable_x64(False):
        want = np.asarray(w.final_poses(refs.astype(np.float32), steps=60))
    for out in outs:
        np.testing.assert_array_equal(np.load(out), want)


def test_use_cpu_devices_before_and_after_jax_starts():
    script = """
import json, jax
from wmr_jax import sharding
first = sharding.use_cpu_devices(3)
jax.numpy.zeros(1).block_until_ready()
print(json.dumps([first, sharding.use_cpu_devices(5), len(jax.devices())]))
"""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=TIMEOUT_S
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    # Three devices once asked before JAX started; too late to change afterwards.
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == [3, 3, 3]
    with pytest.raises(ValueError, match="count = 0"):
        sharding.use_cpu_devices(0)


def test_shard_validates_and_documents_padding():
    with pytest.raises(ValueError, match="leading lengths"):
        sharding.shard((np.zeros((4, 3)), np.zeros(5)))
    with pytest.raises(ValueError, match="leading lengths"):
        sharding.shard(np.float64(1.0))
    with pytest.raises(ValueError, match="at least one device"):
        sharding.shard(np.zeros((4, 3)), devices=[])
    one = sharding.shard(np.zeros((5, 3)))  # one device here: no padding
    assert one.n == one.n_padded == 5
    assert "jax.distributed.initialize" in sharding.multihost_recipe()
