"""Throughput of the simulator in robot-steps per second (the engine of ``wmr-jax bench``).

One robot-step is one robot over one control period. The cases (``CASES``) are
timed beside the ideal loop's NumPy baselines (the scalar reference, and
``numpy_final_poses``); cases compared with each other are timed in alternation,
under the same load: compare ratios of one run, not rates across runs.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import resource
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import check_int, check_number
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.oracle import reference
from wmr_jax._src.oracle.numpy_batch import numpy_final_poses
from wmr_jax._src.sim import loops, rollout
from wmr_jax._src.sim.poses import MAX_SAMPLES, sample_poses
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.sim.sensing.disturbances import sample_disturbance
from wmr_jax._src.sim.sensing.loop import ClosedLoop, _disturbed_jit, prepare_disturbed
from wmr_jax._src.sim.sharding import shard
from wmr_jax._src.studies.bench_timing import Timing, environment, time_group

DEFAULT_SIZES = (1_000, 10_000, 100_000)
DEFAULT_STEPS = 100
DEFAULT_REPEATS = 5
DEFAULT_REFERENCE_POSES = 20
DTYPES = ("float32", "float64")
# The smooth law used for the gradient of the tuning loss, as tuning anneals it.
TUNING_TEMPERATURE = 0.05


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """What ``run_benchmark`` measures.

    Attributes:
        sizes: batch sizes N.
        steps: control periods per run.
        repeats: timed calls per case (the median is reported).
        dtype: ``"float32"`` or ``"float64"``.
        reference_poses: poses the scalar reference is timed on.
        cases: which cases to run, from ``CASES``; empty: every case.
        seed: seed of the reference poses (``wmr_jax.sample_poses``).
        wait_idle: before each round of timed calls, wait up to this many
            seconds for other processes to leave the CPU.
        robot: the robot every case runs (one ``Robot``); ``None``: ``Robot()``.
    """

    sizes: tuple[int, ...] = DEFAULT_SIZES
    steps: int = DEFAULT_STEPS
    repeats: int = DEFAULT_REPEATS
    dtype: str = "float32"
    reference_poses: int = DEFAULT_REFERENCE_POSES
    cases: tuple[str, ...] = ()
    seed: int = 0
    wait_idle: float = 0.0
    robot: Any = None


CASES = (
    "final_poses",
    "final_poses_sharded",
    "final_poses_nonideal",
    "batch_rollout",
    "grad_final_pose_loss",
    "grad_tuning_loss",
    "grad_robust_loss",
    "disturbed_estimator",
    "c_controller",
    "numpy_batch",
    "scalar_reference",
)


def _check_config(config: BenchConfig) -> BenchConfig:
    """Validate ``config`` (before any tracing); return it with ``cases`` filled in."""
    if not isinstance(config, BenchConfig):
        raise ValueError(
            f"config is a {type(config).__name__}; allowed: a BenchConfig (fields as keywords)"
        )
    for name in ("sizes", "cases"):
        if isinstance(getattr(config, name), (str, bytes)):
            value = getattr(config, name)
            raise ValueError(
                f"{name} = {value!r} is not allowed; allowed: a sequence, e.g. ({value!r},)"
            )
    if not config.sizes:
        raise ValueError("sizes = () is not allowed; allowed: one or more integers >= 1")
    for i, n in enumerate(config.sizes):
        check_int(f"sizes[{i}]", n, 1, MAX_SAMPLES)
    for name in ("steps", "repeats", "reference_poses"):
        check_int(name, getattr(config, name))
    check_int("seed", config.seed, 0, 2**32 - 1 - max(config.sizes))
    check_number("wait_idle", config.wait_idle, closed=True, unit="s")
    if config.dtype not in DTYPES:
        raise ValueError(
            f"dtype = {config.dtype!r} is not allowed; allowed: {', '.join(map(repr, DTYPES))}"
        )
    unknown = [c for c in config.cases if c not in CASES]
    if unknown:
        raise ValueError(f"cases = {unknown!r} are not known; allowed: {', '.join(CASES)}")
    if config.robot is not None:
        validate_one_robot(config.robot, "the benchmark")
    return dataclasses.replace(config, cases=tuple(config.cases) or CASES)


def run_benchmark(
    config: BenchConfig,
    *,
    log: Callable[[str], None] | None = None,
    on_size: Callable[[dict], None] | None = None,
) -> dict:
    """Run the benchmark and return its results as a JSON-ready dict.

    Args:
        config: what to measure.
        log: called with one line per finished case (progress).
        on_size: called before the first batch size and after each one but
            the last with the results so far (as returned, ``"finished":
            False``), so that an interrupted run can keep the sizes it finished.

    Returns:
        ``{"environment", "config", "robot", "robot_label", "rows", "ratios",
        "peak_rss_mb", "finished"}`` (``finished`` True here); each row has
        ``case``, ``n``, ``steps``, ``run_s``, ``compile_s``,
        ``robot_steps_per_s``, ``runs_s``, ``others_cpu`` (cores),
        ``page_faults`` (per call), or ``skipped`` with a reason; ``ratios`` maps ``"N=<n>"`` to
        the speed-ups of ``final_poses`` over the baselines and the cost of
        each derivative over its forward pass.
    """
    config = _check_config(config)
    for name, hook in (("log", log), ("on_size", on_size)):
        if hook is not None and not callable(hook):
            raise ValueError(f"{name} = {hook!r} is not allowed; allowed: a function, or None")
    if config.dtype == "float64" and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    if config.dtype == "float32" and jax.config.jax_enable_x64:
        raise ValueError(
            "dtype = 'float32' is not allowed while jax_enable_x64 is on; "
            "allowed: 'float64', or turn jax_enable_x64 off"
        )
    say = log or (lambda line: None)
    rows: list[dict] = []
    if on_size is not None:
        on_size(_results(config, rows, finished=False))
    with warnings.catch_warnings():
        # The paper's gains trip the wheel-speed warning on every call.
        warnings.simplefilter("ignore")
        for n in config.sizes:
            bench = _SizeBench(config, n)
            for row in bench.rows(scalar=n == max(config.sizes)):
                rows.append(row)
                rate = row.get("robot_steps_per_s")
                text = row.get("skipped") or (f"{rate:.3e} robot-steps/s" if rate else "")
                say(f"{row['case']:<22} N={row['n']!s:<8} {text}")
            if on_size is not None and n != config.sizes[-1]:
                on_size(_results(config, rows, finished=False))
    return _results(config, rows, finished=True)


def _results(config: BenchConfig, rows: list[dict], *, finished: bool) -> dict:
    """``run_benchmark``'s dict of ``rows``."""
    from wmr_jax._src.studies.maps import robot_record

    fields = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    return {
        "environment": environment(),
        "config": {name: value for name, value in fields.items() if name != "robot"},
        **robot_record(Robot() if config.robot is None else config.robot),
        "rows": list(rows),
        "ratios": _ratios(rows),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "finished": finished,
    }


class _SizeBench:
    """The cases of one batch size ``n``, each a step that returns its rows."""

    def __init__(self, config: BenchConfig, n: int) -> None:
        self.config, self.n, self.gains, self.steps = config, n, Gains(), config.steps
        self.robot = config.robot
        dtype = np.float32 if config.dtype == "float32" else np.float64
        self.refs_np = np.asarray(sample_poses(config.seed + n, n), dtype=dtype)
        self.refs = jnp.asarray(self.refs_np)

    def time(self, calls: dict[str, tuple[Callable[[], Any], bool]]) -> dict[str, Timing]:
        return time_group(calls, self.config.repeats, wait_idle=self.config.wait_idle)

    def row(self, case: str, timing: Timing | None, n: int | None = None, **extra: Any) -> dict:
        """The row of ``case`` over ``n`` poses (default the batch size)."""
        n = self.n if n is None else n
        row: dict[str, Any] = {"case": case, "n": n, "steps": self.steps}
        if timing is not None:
            row.update(
                run_s=timing.run_s,
                compile_s=timing.compile_s,
                robot_steps_per_s=n * self.steps / timing.run_s if timing.run_s > 0 else None,
                runs_s=timing.runs_s,
                others_cpu=timing.others_cpu,
                page_faults=timing.page_faults,
            )
        return {**row, **extra}

    def rows(self, *, scalar: bool) -> list[dict]:
        """Return the rows of every chosen case, in the order of the table."""
        cases = self.config.cases
        rows, last = self.baselines(scalar=scalar and "scalar_reference" in cases)
        for case, step in (
            ("final_poses_nonideal", lambda: self.alone("final_poses", "nonideal")),
            ("batch_rollout", lambda: self.alone("batch_rollout", "ideal")),
            ("grad_final_pose_loss", self.final_pose_loss),
            ("grad_tuning_loss", self.tuning_loss),
            ("grad_robust_loss", self.robust_loss),
            ("disturbed_estimator", self.disturbed),
            ("c_controller", self.c_controller),
        ):
            if case in cases:
                rows += step()
        return rows + last

    def baselines(self, *, scalar: bool) -> tuple[list[dict], list[dict]]:
        """Rows of ``final_poses`` (and sharded), then of the baselines, timed interleaved."""
        cases, gains, steps, robot = self.config.cases, self.gains, self.steps, self.robot

        def final_poses_of(refs: Any) -> tuple[Callable[[], Any], bool]:
            return (lambda: rollout.final_poses(refs, gains, steps=steps, robot=robot), True)

        group: dict[str, tuple[Callable[[], Any], bool]] = {}
        if "final_poses" in cases:
            group["final_poses"] = final_poses_of(self.refs)
        if "numpy_batch" in cases:
            group["numpy_batch"] = (
                lambda: numpy_final_poses(self.refs_np, gains, steps=steps),
                False,
            )
        k = self.config.reference_poses
        if scalar:
            scalar_refs = np.asarray(sample_poses(self.config.seed, k), dtype=np.float64)

            def scalar_runs():
                for ref in scalar_refs:
                    reference.reference_rollout(ref, gains, steps=steps, robot=robot)

            group["scalar_reference"] = (scalar_runs, False)
        devices = jax.local_devices()
        if "final_poses_sharded" in cases and len(devices) > 1:
            group["final_poses_sharded"] = final_poses_of(shard(self.refs_np, devices).array)
        t = self.time(group) if group else {}
        first, last = [], []
        if "final_poses" in t:
            first.append(self.row("final_poses", t["final_poses"], velocity="ideal"))
        if "final_poses_sharded" in t:
            sharded = t["final_poses_sharded"]
            first.append(self.row("final_poses_sharded", sharded, devices=len(devices)))
        elif "final_poses_sharded" in cases:
            why = f"skipped: needs 2 or more devices ({len(devices)} here; --cpu-devices K)"
            first.append(self.row("final_poses_sharded", None, skipped=why))
        if "numpy_batch" in t:
            last.append(self.row("numpy_batch", t["numpy_batch"], dtype=self.config.dtype))
        if "scalar_reference" in t:
            note = "float64, one pose at a time"
            last.append(self.row("scalar_reference", t["scalar_reference"], k, note=note))
        return first, last

    def disturbed(self) -> list[dict]:
        """The disturbed loop's jitted core (docs/model.md §7), raw and with each estimator."""
        spec = sample_disturbance(
            jax.random.PRNGKey(self.config.seed), self.refs, self.steps, noise_xy=0.5,
            noise_theta=math.radians(1.0), radius_mismatch=0.03, latency=1.0,
        )  # fmt: skip
        group, start = {}, (0.0, 0.0, 0.0)
        for name, estimator in (("raw", None), ("observer", "observer"), ("ekf", "ekf")):
            args, options = prepare_disturbed(
                spec, self.gains, "shim-sung", estimator, start, 0.033, self.robot, "ideal"
            )
            group[name] = (functools.partial(_disturbed_jit, *args, options=options), True)
        t = self.time(group)
        raw = t["raw"].run_s
        return [
            self.row("disturbed_raw", t["raw"], feedback="raw"),
            *(
                self.row(f"disturbed_{name}", t[name], over_raw=t[name].run_s / raw)
                for name in ("observer", "ekf")
            ),
        ]

    def c_controller(self) -> list[dict]:
        """The exported C controller (``wmr_jax.export``): a gain schedule with its EKF.

        ``N`` controllers with one sample of latency, stepped through noisy poses;
        one foreign call steps all ``N``.
        """
        import tempfile
        from pathlib import Path

        from wmr_jax._src.export import codegen, compiled
        from wmr_jax._src.model.controllers.schedule import SCHEDULE, ScheduleParams

        if compiled.compiler() is None:
            return [self.row("c_controller", None, skipped="skipped: no C compiler")]
        robot = Robot() if self.robot is None else self.robot
        params = ScheduleParams.from_gains(self.gains, robot=robot)
        loop = ClosedLoop(SCHEDULE, params, "ekf", robot)
        with tempfile.TemporaryDirectory() as tmp:
            codegen.write_sources(Path(tmp), codegen.c_sources(loop), loop)
            c = compiled.compile_controller(tmp, build=Path(tmp, "build"))
            code_size = code_bytes(Path(tmp, "wmr_controller.c"), Path(tmp, "build"))
        refs = np.asarray(self.refs_np, dtype=np.float64)
        rng = np.random.default_rng(self.config.seed)
        along = np.linspace(0.0, 1.0, self.steps)[:, None, None] * refs[None]
        measured = np.ascontiguousarray(along + rng.normal(0.0, 0.5, along.shape))

        def run():
            c.start(refs, 1)
            for z in measured:
                c.step(z)

        t = self.time({"c": (run, False)})["c"]
        per_step = t.run_s / (self.n * self.steps) * 1e9
        sizes = {"state_bytes": c.size, "code_bytes": code_size}
        run_as = {"law": "schedule", "feedback": "ekf", "latency": 1}
        return [self.row("c_controller", t, ns_per_step=per_step, **sizes, **run_as)]

    def alone(self, entry: str, velocity: str) -> list[dict]:
        """Time ``final_poses`` or ``batch_rollout`` (``entry``) alone, with ``velocity``'s loop."""
        run = getattr(rollout, entry)
        case = entry + ("_nonideal" if velocity == "nonideal" else "")

        def call():
            return run(self.refs, self.gains, steps=self.steps, velocity=velocity, robot=self.robot)

        return [self.row(case, self.time({case: (call, True)})[case], velocity=velocity)]

    def gain_derivatives(self, loss: Callable) -> list[Callable[[], Any]]:
        """Calls of ``loss(gains, refs)``, its derivative along the gains and its gradient."""

        def along_gains(gains, refs):
            return jax.jvp(lambda g: loss(g, refs), (gains,), (gains,))

        jitted = [loops.jit_top_level(f) for f in (loss, along_gains, jax.value_and_grad(loss))]
        return [lambda f=f: f(self.gains, self.refs) for f in jitted]

    def loss_rows(
        self,
        calls: list[Callable[[], Any]],
        forward_row: tuple[str, dict],
        case: str,
        beside: tuple[str, Callable[[], Any]] | None = None,
    ) -> list[dict]:
        """Time a loss, its derivative along one direction and its gradient (``calls``) together.

        ``1 + jvp_over_forward`` is the gradient's floor. ``beside``: ``(case, call)`` timed
        with them. Returns the rows ``[beside,] forward, jvp_<case>, <case>``.
        """
        names = ("forward", "directional", "gradient")
        group = {name: (call, True) for name, call in zip(names, calls, strict=True)}
        if beside is not None:
            group["beside"] = (beside[1], True)
        t = self.time(group)
        ratio = t["gradient"].run_s / t["forward"].run_s
        jvp_ratio = t["directional"].run_s / t["forward"].run_s
        jvp_case = case.replace("grad_", "jvp_", 1)
        rows = [] if beside is None else [self.row(beside[0], t["beside"])]
        return rows + [
            self.row(forward_row[0], t["forward"], **forward_row[1]),
            self.row(jvp_case, t["directional"], jvp_over_forward=jvp_ratio),
            self.row(case, t["gradient"], grad_over_forward=ratio),
        ]

    def final_pose_loss(self) -> list[dict]:
        """The mean squared final-pose error through ``final_poses``, and its gradient."""
        steps, robot = self.steps, self.robot

        def loss(gains, refs):
            final = rollout.final_poses(refs, gains, steps=steps, robot=robot)
            err = final - refs
            return jnp.mean(err[:, 0] ** 2 + err[:, 1] ** 2 + (1.0 - jnp.cos(err[:, 2])))

        row = ("final_pose_loss", {"of": "mean squared error"})
        return self.loss_rows(self.gain_derivatives(loss), row, "grad_final_pose_loss")

    def tuning_loss(self) -> list[dict]:
        """``wmr_jax.tuning.tuning_loss`` and its gradient, beside the relaxed law it wraps."""
        from wmr_jax import tuning

        horizon, robot = self.steps * DEFAULT_DT, self.robot
        gains, refs, steps = self.gains, self.refs, self.steps

        def loss(g, r):
            return tuning.tuning_loss(
                g, r, temperature=TUNING_TEMPERATURE, horizon=horizon, robot=robot
            )

        def relaxed():
            return rollout.final_poses(
                refs, gains, steps=steps, temperature=TUNING_TEMPERATURE, robot=robot
            )

        row = ("tuning_loss", {"temperature": TUNING_TEMPERATURE})
        # Beside the loss, the relaxed law alone: what the loss adds to it.
        calls = self.gain_derivatives(loss)
        return self.loss_rows(calls, row, "grad_tuning_loss", ("final_poses_relaxed", relaxed))

    def robust_loss(self) -> list[dict]:
        """The robust tuner's loss (schedule, EKF), its ``RobustLoss`` gradient, a logit jvp."""
        from wmr_jax._src.tuning import robust

        robot = Robot() if self.robot is None else self.robot
        joint, dtype = robust.joint_problem(robust.RobustConfig()), self.refs.dtype
        accel = loops.for_robot(loops.Options(), robot, DEFAULT_DT).accel_limit
        loss = robust.RobustLoss(self.steps, joint, accel, None)
        z = jnp.asarray(joint.start_logits(robot), dtype)
        batch = (jax.random.key(self.config.seed), self.refs, self.refs[: max(self.n // 4, 1)])
        temperature, consts = TUNING_TEMPERATURE, (robot, jnp.asarray(DEFAULT_DT, dtype))
        args = (batch, jnp.asarray(temperature, dtype), consts)

        def forward(z, args):
            (key, refs, nonideal), temperature, (robot, dt) = args
            return robust.robust_loss_value(
                z, key, refs, nonideal, temperature, robot, dt, self.steps, joint, accel
            )

        def directional(z, args):
            return jax.jvp(lambda z: forward(z, args), (z,), (jnp.ones_like(z),))

        jitted = [loops.jit_top_level(f) for f in (forward, directional, loss)]
        calls = [lambda f=f: f(z, args) for f in jitted[:2]]
        calls.append(lambda: jitted[2](z, *args))  # the RobustLoss takes them unpacked
        runs = self.n * len(robust.disturbances.STANDARD_CONDITIONS) + len(batch[2])
        return self.loss_rows(calls, ("robust_loss", {"runs": runs}), "grad_robust_loss")


def code_bytes(source: Any, build: Any) -> int | None:
    """Bytes of code and constants of ``source`` compiled with the export's flags and ``-O2``.

    The object's text as ``size`` counts it, else the object file's size (no ``size``
    tool); ``None`` if it does not compile.
    """
    import shutil
    import subprocess

    from wmr_jax._src.export.compiled import CFLAGS, compiler

    obj = build / "wmr_controller.o"
    done = subprocess.run(
        [compiler(), *CFLAGS, "-O2", "-c", str(source), "-o", str(obj)], capture_output=True
    )
    if done.returncode != 0:
        return None
    tool = shutil.which("size")
    if tool:
        done = subprocess.run([tool, str(obj)], capture_output=True, text=True)
        lines = done.stdout.split("\n")
        if done.returncode == 0 and len(lines) > 1:
            return int(lines[1].split()[0])
    return obj.stat().st_size


def _ratios(rows: list[dict]) -> dict[str, Any]:
    """Speed-ups of ``final_poses`` over the baselines, per batch size."""

    def rate(case: str, n: int | None = None) -> float | None:
        for row in rows:
            if row["case"] == case and (n is None or row["n"] == n):
                return row.get("robot_steps_per_s")
        return None

    scalar = rate("scalar_reference")
    out: dict[str, Any] = {}
    sizes = sorted({row["n"] for row in rows if row["case"] != "scalar_reference"})
    for n in sizes:
        entry: dict[str, Any] = {}
        numpy_rate = rate("numpy_batch", n)
        jax_rates = (("", rate("final_poses", n)), ("sharded_", rate("final_poses_sharded", n)))
        for name, value in jax_rates:
            if value and numpy_rate:
                entry[f"{name}vs_numpy_batch"] = value / numpy_rate
            if value and scalar:
                entry[f"{name}vs_scalar_reference"] = value / scalar
        # Ratios the rows carry: a derivative over its forward pass, an estimator over raw.
        for key in ("grad_over_forward", "jvp_over_forward", "over_raw"):
            for r in rows:
                if r["n"] == n and key in r:
                    entry[f"{r['case']}_{key.removeprefix('grad_').removeprefix('jvp_')}"] = r[key]
        # Costs per robot-step, measured in this run: the rate of the first over the second.
        for key, fast, slow in (
            ("tuning_loss_over_relaxed", "final_poses_relaxed", "tuning_loss"),
            ("tuning_loss_over_final_poses", "final_poses", "tuning_loss"),
            ("nonideal_over_ideal", "final_poses", "final_poses_nonideal"),
            ("relaxed_over_final_poses", "final_poses", "final_poses_relaxed"),
        ):
            top, bottom = rate(fast, n), rate(slow, n)
            if top and bottom:
                entry[key] = top / bottom
        if entry:
            out[f"N={n}"] = entry
    return out
