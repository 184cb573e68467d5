"""Run the closed loop on an identified robot while the controller believes the base robot.

``identified.json`` says how the true robot differs from the one the
controller was written for: its wheels' scales, its half-track, its wheel
loop's gain, its latency and its tracker's noise. A run on it is the one
closed-loop step with ``model.TrueRobot`` as its disturbance: the law and
the firmware keep ``BASE``, the body moves as the identified robot does.
In the ideal velocity loop the wheel loop's gain plays no part; in the
non-ideal loop the wheel controller keeps the base's model.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.identify import model
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import loops, metrics
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.sim.rollout import DEFAULT_DT, Trajectory
from wmr_jax._src.sim.sensing import loop as sensing_loop
from wmr_jax._src.sim.sensing.disturbances import Disturbance

_KEYS = ("robot", "base_robot", "wheel_scale", "latency_samples", "noise")


def is_identified(source: Any) -> bool:
    """Whether ``source`` names an ``identified.json`` written by ``identify``."""
    if source is None or not str(source).endswith(".json") or not Path(source).is_file():
        return False
    try:
        content = json.loads(Path(source).read_text())
    except ValueError:
        return False
    return isinstance(content, dict) and "wheel_scale" in content


def check_identified(content: Any, where: str) -> Robot:
    """Check the content of an ``identified.json`` (before any run); return its base robot.

    ``where`` names it in the one-line ``ValueError``.
    """
    from wmr_jax._src.model.robots import robot_from_values

    if not isinstance(content, Mapping):
        raise ValueError(f"{where} is a {type(content).__name__}; allowed: identify's output")
    missing = [k for k in _KEYS if k not in content]
    if missing:
        raise ValueError(f"{where} lacks {', '.join(missing)}; allowed: identify's output")
    latency = content["latency_samples"]
    whole = isinstance(latency, int) and not isinstance(latency, bool)  # JSON true is no count
    if not whole or not 0 <= latency <= model.MAX_LATENCY:
        raise ValueError(
            f"{where}: latency_samples = {latency!r} is not allowed; allowed: an "
            f"integer 0-{model.MAX_LATENCY}"
        )
    for block, names, low in (
        ("wheel_scale", ("left", "right"), "> 0"),
        ("robot", ("half_track", "speed_gain"), "> 0"),
        ("noise", ("sigma_xy", "sigma_theta"), ">= 0"),
    ):
        values = content[block]
        for name in names:
            value = values.get(name) if isinstance(values, Mapping) else None
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            bound = number and math.isfinite(value) and (value >= 0 if low == ">= 0" else value > 0)
            if not bound:
                raise ValueError(
                    f"{where}: {block}.{name} = {value!r:.40} is not allowed; allowed: a finite "
                    f"number {low}"
                )
    return robot_from_values(content["base_robot"], f"{where}: base_robot")


def read_identified(source: Any, dt: float = DEFAULT_DT) -> tuple[Robot, dict[str, Any]]:
    """Return ``(base robot, identified content)`` of an ``identified.json``, checked.

    ``dt``: the period of the runs to come. A latency identified in samples of
    another period lasts another time in them, which is warned of.
    """
    content = json.loads(Path(source).read_text())
    base = check_identified(content, f"--robot {source}")
    latency = content["latency_samples"]
    logged = content.get("dt", dt)  # written by identify; a file without it is not judged
    number = isinstance(logged, (int, float)) and not isinstance(logged, bool)
    if not (number and math.isfinite(logged) and logged > 0):
        raise ValueError(
            f"--robot {source}: dt = {logged!r:.40} is not allowed; allowed: the logs' period, "
            "a finite number of s > 0"
        )
    # Within 2 %: a tracker at 30 Hz (0.0333 s) and the 0.033 s period are one period.
    if latency and not math.isclose(logged, dt, rel_tol=0.02):
        warnings.warn(
            f"--robot {source} was identified from logs at a period of {logged:g} s and these "
            f"runs step at {dt:g} s: its latency of {latency} samples lasts "
            f"{1000 * latency * dt:.0f} ms here against {1000 * latency * logged:.0f} ms in the "
            f"logs (log at {dt:g} s: identify --plan --plan-dt {dt:g}; simulate takes --dt)",
            stacklevel=2,
        )
    return base, content


def loaded_identified(source: Any, dt: float = DEFAULT_DT) -> Any:
    """``(LoadedRobot of the base, content)`` of an ``identify`` output, else ``None``.

    ``dt``: the period of the runs to come (``read_identified``).

    The loaded robot's note says, in one line, that the runs are on the
    identified robot while the controller believes its base.
    """
    from wmr_jax._src.model.robots import LoadedRobot

    if not is_identified(source):
        return None
    base, content = read_identified(source, dt)
    note = (
        f"the true robot is the one identified in {source} (wheel scales, half-track "
        f"{content['robot']['half_track']:.4g} cm, latency {content['latency_samples']}, "
        "tracker noise); the controller believes its base robot"
    )
    return LoadedRobot(base, str(source), note), content


def tuned_for_identified(saved: Any, content: dict[str, Any]) -> bool:
    """Whether ``saved`` (a gain file's robot) is the robot ``tune --robot identified.json`` reads.

    Such gains run on the controller that believes the base robot.
    """
    from wmr_jax._src.model.robots import same_robot

    if saved is None:
        return False
    names = {f.name for f in dataclasses.fields(Robot)}
    fields = {**content["base_robot"], **content["robot"]}
    return same_robot(saved, Robot(**{f: float(v) for f, v in fields.items() if f in names}))


def true_robot(identified: dict[str, Any], base: Robot, noise: Any, dtype: Any) -> model.TrueRobot:
    """The ``TrueRobot`` disturbance of ``identified`` with measurement noise ``noise``."""
    true = identified["robot"]
    scale = [identified["wheel_scale"]["left"], identified["wheel_scale"]["right"]]
    return model.TrueRobot(
        jnp.asarray(noise, dtype),
        jnp.asarray(scale, dtype),
        jnp.asarray(base.half_track, dtype),
        jnp.asarray(int(identified["latency_samples"]), dtype),
        jnp.asarray(true["half_track"], dtype),
        jnp.asarray(true["speed_gain"], dtype),
    )


def _metrics_single(ref, spec, params, estimate, init, robot, dt, options):
    """One run toward ``ref`` on the true robot ``spec``, streaming the §6 metrics."""
    final, acc, _ = loops.scan_closed_loop(
        ref,
        params,
        init,
        robot,
        dt,
        options,
        disturbance=spec,
        estimate=estimate,
        fold=sensing_loop.metrics_fold(ref),
        acc=metrics.stream_start(ref.dtype),
    )
    return sensing_loop.metrics_result(acc, final, ref, dt)


@functools.partial(jax.jit, static_argnames=("options",))
def _metrics_batch(refs, spec, params, estimate, init, robot, dt, options):
    axes = model.TrueRobot(0, None, None, None, None, None)
    return jax.vmap(
        lambda r, s: _metrics_single(r, s, params, estimate, init, robot, dt, options),
        in_axes=(0, axes),
    )(refs, spec)


def identified_metrics(
    disturbance: Disturbance,
    params: Any,
    *,
    identified: dict[str, Any],
    controller: Any,
    estimator: Any = None,
    dt: float,
    robot: Robot,
    velocity: str = "ideal",
    x64: bool = True,
) -> PoseMetrics:
    """The ``docs/model.md §6`` metrics of a batch of runs on the identified robot.

    ``disturbance`` carries the references and their measurement noise
    ``(N, steps, 3)`` (its wheel factors and latency are checked and set
    aside): the wheel scales, half-track, wheel-loop gain and latency are
    ``identified``'s. The controller and its estimator believe ``robot``
    (the base). Checked and prepared as ``disturbed_metrics`` prepares its
    runs, then run through the same step with ``model.TrueRobot`` as the
    disturbance, the plug-in ``identified_rollout`` runs.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        delay = int(identified["latency_samples"])
        args, options = sensing_loop.prepare_disturbed(
            disturbance._replace(delay=np.float64(delay)),
            params, controller, estimator, (0.0, 0.0, 0.0), dt, robot, velocity,
        )  # fmt: skip
        spec, params, estimate, init, robot, dt = args
        options = loops.for_robot(options, robot, dt)
        options = dataclasses.replace(options, max_delay=max(1, delay), remat=False)
        plug = true_robot(identified, robot, spec.noise, dt.dtype)
        out = _metrics_batch(spec.ref, plug, params, estimate, init, robot, dt, options)
        return PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})


def identified_rollout(
    ref: Any,
    params: Any,
    *,
    controller: Any,
    init: Any,
    dt: float,
    steps: int,
    velocity: str,
    base: Robot,
    identified: dict[str, Any],
    seed: int = 0,
    noise: bool = True,
) -> Trajectory:
    """One run of ``controller`` (believing ``base``) on the identified robot.

    The law sees the pose with the identified tracker noise (``noise``) and
    acts ``latency_samples`` late; the region is ``-1`` (the law sees a
    measurement, not the true pose).
    """
    with jax.enable_x64(True):
        sigma = identified["noise"]
        delay = int(identified["latency_samples"])
        draws = jax.random.normal(jax.random.PRNGKey(seed), (steps, 3), jnp.float64)
        spread = jnp.asarray([sigma["sigma_xy"], sigma["sigma_xy"], sigma["sigma_theta"]])
        spec = true_robot(identified, base, draws * spread * (1.0 if noise else 0.0), jnp.float64)
        options = loops.for_robot(
            loops.Options(
                steps=steps,
                velocity=velocity,
                controller=controller,
                max_delay=max(1, delay),
                remat=False,
            ),
            base,
            dt,
        )
        init = jnp.asarray(init, jnp.float64)
        base64 = jax.tree.map(jnp.float64, base)
        params = jax.tree.map(jnp.float64, params)
        _, _, (poses, out, _) = jax.jit(
            lambda s: loops.scan_closed_loop(
                jnp.asarray(ref, jnp.float64),
                params,
                init,
                base64,
                jnp.float64(dt),
                options,
                disturbance=s,
                record=True,
            )
        )(spec)
        return Trajectory(
            np.asarray(jnp.concatenate([init[None], poses])),
            np.asarray(out.v),
            np.asarray(out.omega),
            np.asarray(out.region),
            np.asarray(out.wheel_speeds),
            np.asarray(out.distance),
        )
