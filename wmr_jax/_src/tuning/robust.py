"""Robust tuning: controller and estimator tuned together (docs/model.md §7, §9).

The loss is the relaxed arrival time of ``tuning_loss`` (plus its log-error
shaping), averaged over domain-randomised runs: the standard conditions
(nominal, one-sample latency, pose noise, both) in the ideal loop, each with
every wheel's radius off by up to ±3 % and the noise scaled per run by a
level drawn from ``U(0, 2)`` (up to twice ``RobustConfig.noise_xy`` and
``noise_theta``, by default the standard σ_xy = 0.5 cm, σ_θ = 1°), and a
group in the non-ideal loop with ±20 % body mass and latency with
probability ½ besides. Every disturbance is drawn inside the
loss from a PRNG key by ``sample_disturbance`` and run by
``sensing.loop.disturbed_run``: the same code as the Monte Carlo.

By default the gain schedule and the EKF are tuned together
(``RobustConfig.problem = "schedule"``, ``estimator = "ekf"``: tuned the same
way, the filter beat the observer, docs/robustness.md); the 7 fixed gains
with raw feedback remain (``problem = "fixed"``, ``estimator = None``).
Every point of the searched cube is feasible (``problems.Problem``,
``estimation.EstimatorBox``). Random search and
CMA-ES get the same wall time on the same cube and score candidates with
the hard law under the standard conditions.

On another robot than the paper's (``tune_robust(robot=...)``) the loop is
tuned within that robot's wheel budget, with its speed limiter where it
gives acceleration limits (docs/model.md §4.2.2), over the horizon of the
studies that judge it (``robustness.study_horizon``), and judged there.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from wmr_jax._src.checks import (
    as_poses,
    check_bool,
    check_callable,
    check_int,
    check_key,
    check_number,
    float_dtype,
    require_unbatched,
)
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.controllers.schedule import KNOTS
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R, DEFAULT_TOL_THETA
from wmr_jax._src.sim.poses import horizon_steps, sample_poses
from wmr_jax._src.sim.rollout import DEFAULT_DT, check_temperature
from wmr_jax._src.sim.sensing import disturbances, loop
from wmr_jax._src.sim.sensing.disturbances import STANDARD_MISMATCH
from wmr_jax._src.sim.sensing.estimators import ESTIMATORS, OBSERVER_KNOTS
from wmr_jax._src.sim.sensing.loop import ClosedLoop
from wmr_jax._src.studies import conditions, robustness
from wmr_jax._src.tuning import centred
from wmr_jax._src.tuning.estimation import EstimatorBox, estimator_box
from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED, held_out_poses
from wmr_jax._src.tuning.loss import LossWeights, arrival_terms, capped_mean
from wmr_jax._src.tuning.parametrisation import checked_point, paper_feasible_gains
from wmr_jax._src.tuning.problems import FIXED, Problem, schedule_problem
from wmr_jax._src.tuning.search import search_loop
from wmr_jax._src.tuning.training import anneal, best_iteration, optimizer

__all__ = [
    "JointProblem",
    "RobustConfig",
    "joint_problem",
    "robust_gains",
    "robust_loss",
    "robust_score",
    "tune_robust",
]


# Seed of the noise the standard conditions are judged under: that of
# ``wmr-jax robustness`` at its default ``--seed``, so both write the same table.
EVAL_NOISE_SEED = 0

_FAILURE_FACTOR = 2.0  # black-box score of a run that never arrives, in horizons
_NOISE_LEVEL_MAX = 2.0  # training noise up to twice the sensor's level
# The standard pose noise (σ_xy cm, σ_θ degrees): that of the noisy standard conditions.
_STANDARD_NOISE = next((c[1], c[2]) for c in disturbances.STANDARD_CONDITIONS if c[1])


@dataclasses.dataclass(frozen=True)
class RobustConfig:
    """Settings of ``tune_robust``.

    Attributes:
        iters: Adam iterations.
        poses: reference poses per standard condition per iteration (ideal loop).
        nonideal_poses: poses of the randomised non-ideal group per iteration
            (0: none).
        seed: seed of the training draws and of the searches.
        learning_rate: Adam's step in logit space (cosine-decayed to a tenth).
        temperature_start: smooth-law temperature of the first iteration.
        temperature_end: of the last (annealed geometrically).
        eval_poses: held-out poses of the hard-law table.
        search_poses: poses per condition that random search and CMA-ES score on.
        compare: also run random search and CMA-ES for the tuning's wall time.
        problem: ``"schedule"`` (the gain schedule, default) or ``"fixed"``
            (the 7 gains).
        estimator: ``"ekf"`` (default), ``"observer"``, or ``None`` (raw
            feedback), tuned together with the controller.
        knots: knots per table of the schedule.
        observer_knots: knots per gain table of the observer.
        validate_every: iterations between hard-law scores of the iterate
            under the standard conditions (``robust_score``) on the
            validation poses; the start and the last iterate are always
            scored, and the best scored iterate is the result.
        validation_poses: poses of that score, drawn from ``seed`` apart from
            the training, search and held-out poses.
        noise_xy: the sensor's position noise σ_xy, cm: the training draws
            it up to twice this (``U(0, 2)`` per run), and the validation,
            the searches and the evaluation judge the noise and both
            conditions at it.
        noise_theta: the sensor's heading noise σ_θ, degrees (as ``noise_xy``).
        around: ``centred.Centred`` ranges of an identified robot: the
            training draws its runs from them instead of the standard
            conditions (``centred.for_config``); ``None``: the standard ones.
    """

    # choice: 600. At 300 the loop under noise and latency together came out
    # at 0.62-0.64 s on the held-out poses (seeds 0-2); at 600, 0.55-0.59 s,
    # every other condition a little faster too (docs/robustness.md).
    iters: int = 600
    poses: int = 32
    nonideal_poses: int = 8
    seed: int = 0
    learning_rate: float = 0.1
    temperature_start: float = 0.1
    temperature_end: float = 0.003
    eval_poses: int = EVAL_POSES
    search_poses: int = 32
    compare: bool = True
    problem: str = "schedule"
    estimator: str | None = "ekf"
    knots: int = KNOTS
    observer_knots: int = OBSERVER_KNOTS
    validate_every: int = 25
    validation_poses: int = 32
    noise_xy: float = 0.5
    noise_theta: float = 1.0
    around: centred.Centred | None = None

    def validate(self) -> RobustConfig:
        """Check every field; return ``self`` (``ValueError`` naming the field)."""
        for name in (
            "iters", "poses", "eval_poses", "search_poses", "validate_every", "validation_poses"
        ):  # fmt: skip
            check_int(name, getattr(self, name), 1)
        check_int("nonideal_poses", self.nonideal_poses, 0)
        check_int("seed", self.seed, 0, 2**32 - 1)
        check_number("learning_rate", self.learning_rate)
        for name in ("temperature_start", "temperature_end"):
            check_temperature(name, getattr(self, name))
        check_bool("compare", self.compare)
        check_number("noise_xy", self.noise_xy, closed=True, unit="cm")
        check_number("noise_theta", self.noise_theta, closed=True, unit="degrees")
        if self.problem not in ("fixed", "schedule"):
            raise ValueError(
                f"problem = {self.problem!r} is not allowed; allowed: 'fixed' or 'schedule'"
            )
        if self.estimator is not None and self.estimator not in ESTIMATORS:
            raise ValueError(
                f"estimator = {self.estimator!r} is not allowed; allowed: None, "
                f"{', '.join(repr(n) for n in ESTIMATORS)}"
            )
        if self.around is not None and not isinstance(self.around, centred.Centred):
            raise ValueError(
                f"around = {self.around!r:.80} is not allowed; allowed: None or centred.around "
                "of an identified.json"
            )
        joint_problem(self)  # checks the knot counts
        return self

    @property
    def noise(self) -> tuple[float, float]:
        """``(σ_xy cm, σ_θ degrees)`` of the sensor tuned for."""
        return float(self.noise_xy), float(self.noise_theta)


@dataclasses.dataclass(frozen=True)
class JointProblem:
    """A controller's cube and its estimator's, searched as one (hashable: static under jit).

    Attributes:
        problem: the controller's ``Problem``.
        estimator: the estimator's ``EstimatorBox``, or ``None`` (raw feedback).
    """

    problem: Problem
    estimator: EstimatorBox | None

    @property
    def dim(self) -> int:
        """Dimension of the joint cube: the controller's, then the estimator's."""
        return self.problem.dim + (self.estimator.dim if self.estimator else 0)

    def from_unit(self, u: Any, robot: Robot) -> ClosedLoop:
        """The closed loop of ``u (dim,)``: feasible gains, ``R_e ≤ tol_r``, a valid estimator."""
        n = self.problem.dim
        params = _capped(self.problem.from_unit(u[:n], robot))
        estimate = self.estimator.from_unit(u[n:]) if self.estimator else None
        return ClosedLoop(self.problem.controller, params, estimate)

    def from_logits(self, z: Any, robot: Robot) -> ClosedLoop:
        """The closed loop of logits ``z`` (``u = σ(z)``, any real ``(dim,)``)."""
        z = checked_point("z", z, self.dim, unit=False)
        return self.from_unit(1.0 / (1.0 + jnp.exp(-z)), robot)

    def start_logits(self, robot: Robot) -> np.ndarray:
        """Logits of the start: the problem's start and the estimator's defaults."""
        parts = [self.problem.start(robot)]
        if self.estimator:
            parts.append(self.estimator.start())
        u = np.concatenate(parts)
        return np.log(u) - np.log1p(-u)

    @property
    def options_estimator(self) -> Any:
        return ESTIMATORS[self.estimator.name] if self.estimator else None


def joint_problem(config: RobustConfig) -> JointProblem:
    """The ``JointProblem`` that ``config`` tunes."""
    problem = FIXED if config.problem == "fixed" else schedule_problem(config.knots)
    box = None
    if config.estimator is not None:
        box = estimator_box(config.estimator, config.observer_knots)
    return JointProblem(problem, box)


# choice: the robust tuner keeps R_e ≤ tol_r. Inside R_e (Region 0) the law
# steers the heading only, so a robot that enters it more than tol_r from the
# goal can stay there; the relaxed law blurs this trap and, unconstrained,
# Adam found R_e ≈ 1.4 cm, with hard-law success 59 % in the nominal model.
_R_E_MAX = 1.0 * DEFAULT_TOL_R


def _capped(params: Any) -> Any:
    return params.replace(r_e=jnp.minimum(params.r_e, _R_E_MAX))


def _concrete(closed: ClosedLoop) -> ClosedLoop:
    """The loop with every parameter a Python float (for files and the hard-law judge)."""
    return closed._replace(
        params=jax.tree.map(float, closed.params),
        estimator=jax.tree.map(float, closed.estimator),
    )


def robust_gains(z: jax.Array, robot: Robot) -> Gains:
    """The fixed gains of logits ``z`` (7,) with ``R_e ≤ tol_r`` (cm)."""
    return JointProblem(FIXED, None).from_logits(z, robot).params


def _relaxed_arrival(poses: jax.Array, ref: jax.Array, dt: jax.Array) -> jax.Array:
    """Relaxed arrival time plus log-error shaping of one recorded run, s.

    The quantity of ``tuning_loss``'s per-run term in the ideal loop (the
    same ``arrival_terms``, tolerances and weights), computed from the run's
    recorded poses: ``disturbed_run`` records the trajectory, while
    ``tuning_loss`` streams the sum through the rollout's scan (``S ← a (S +
    1)`` forwards, not the reversed cumulative product). The two agree to
    rounding, not bit for bit, so each tuner keeps its own.
    """
    weights = LossWeights()
    err = law.polar_error(poses, ref)
    dist = err.r**2 / DEFAULT_TOL_R**2
    head = err.sin_theta**2 / math.sin(DEFAULT_TOL_THETA) ** 2
    arrived, log_error = arrival_terms(dist, head, weights.arrival_softness)
    # Σ_k Π_{j≥k} a_j: the runs of arrived samples that last to the end.
    settled = jnp.sum(jnp.cumprod(arrived[::-1]))
    soft = dt * (1.0 + arrived.shape[0] - settled)
    return soft + weights.shaping * dt * jnp.sum(log_error)


def _group_grads(z, spec, joint, robot, dt, options):
    """Per-run ``(loss (N,), gradient (N, dim))`` w.r.t. the logits ``z`` of one batch of runs."""
    init = jnp.zeros((3,), dt.dtype)

    def run_loss(z, spec):
        closed = joint.from_logits(z, robot)
        _, _, (poses, _, _) = loop.disturbed_run(
            spec, closed.params, init, robot, dt, options, estimate=closed.estimator, record=True
        )
        return _relaxed_arrival(poses, spec.ref, dt)

    spec_axes = disturbances.Disturbance(0, 0, 0, 0)
    return jax.vmap(jax.value_and_grad(run_loss), in_axes=(None, spec_axes))(z, spec)


def _specs(key, refs, nonideal_refs, steps, temperature, joint, accel_limit=False, noise=None):
    """The loss's batches: ``[(spec, options)]``, drawn from ``key``.

    ``accel_limit``: the ideal loop's speed limiter (docs/model.md §4.2.2);
    ``noise``: ``(σ_xy cm, σ_θ degrees)`` of the noisy runs, each scaled by
    a level ``U(0, 2)`` (default the standard 0.5 cm, 1°).
    """
    keys = jax.random.split(key, 2 * len(disturbances.STANDARD_CONDITIONS) + 1)
    ideal = loops.Options(
        steps=steps,
        controller=joint.problem.controller,
        temperature=temperature,
        estimator=joint.options_estimator,
        accel_limit=accel_limit,
    )
    if isinstance(noise, centred.Centred):  # around an identified robot (RobustConfig.around)
        return centred.batches(key, refs, nonideal_refs, steps, ideal, noise)
    noise_xy, noise_deg = _STANDARD_NOISE if noise is None else noise
    n = refs.shape[0]
    specs = []
    for i, (_, sxy, sdeg, latency) in enumerate(disturbances.STANDARD_CONDITIONS):
        if sxy:
            sxy, sdeg = noise_xy, noise_deg
        level = jax.random.uniform(keys[2 * i], (n,), refs.dtype, 0.0, _NOISE_LEVEL_MAX)
        specs.append(
            disturbances.sample_disturbance(
                keys[2 * i + 1],
                refs,
                steps,
                noise_xy=sxy * level,
                noise_theta=math.radians(sdeg) * level,
                latency=float(latency),
                radius_mismatch=STANDARD_MISMATCH,
            )
        )
    # One batch for all conditions: one scan to compile, not four.
    batches = [(jax.tree.map(lambda *leaves: jnp.concatenate(leaves), *specs), ideal)]
    if nonideal_refs.shape[0]:
        k_level, k_spec = jax.random.split(keys[-1])
        level = jax.random.uniform(
            k_level, (nonideal_refs.shape[0],), refs.dtype, 0.0, _NOISE_LEVEL_MAX
        )
        spec = disturbances.sample_disturbance(
            k_spec,
            nonideal_refs,
            steps,
            noise_xy=noise_xy * level,
            noise_theta=math.radians(noise_deg) * level,
            latency=0.5,
            radius_mismatch=STANDARD_MISMATCH,
            mass_mismatch=0.2,
        )
        nonideal = dataclasses.replace(ideal, velocity="nonideal", accel_limit=False)
        batches.append((spec, nonideal))
    return batches


def _accel_limit(robot: Robot, dt: Any) -> bool:
    """Whether the ideal loop on ``robot`` has its speed limiter (``loops.for_robot``)."""
    return loops.for_robot(loops.Options(), robot, dt).accel_limit


def robust_loss(
    z,
    key,
    refs,
    nonideal_refs,
    temperature,
    robot,
    dt,
    steps,
    joint=None,
    accel_limit=None,
    noise=None,
):
    """The robust tuning loss of logits ``z`` and its robust gradient (traceable).

    Runs: ``refs`` under each standard condition with wheel mismatch and
    randomised noise (ideal loop), and ``nonideal_refs`` (may be empty)
    under randomised disturbances in the non-ideal loop. As in
    ``robust_gradient``, each run's gradient is capped at the batch median
    norm and non-finite ones are dropped: a run grazing a switching surface
    has a gradient orders of magnitude above the rest.

    Args:
        joint: the ``JointProblem`` of ``z``; default the 7 fixed gains with
            raw feedback.
        accel_limit: the ideal loop's speed limiter of the robot's
            acceleration limits (docs/model.md §4.2.2); ``None`` decides by
            ``loops.for_robot`` (on for a traced robot, whose limits cannot
            be seen).
        noise: ``(σ_xy cm, σ_θ degrees)`` of the sensor (``RobustConfig.noise``);
            default the standard 0.5 cm, 1°; a ``centred.Centred`` draws
            every run from its ranges instead (``RobustConfig.around``).

    Returns:
        ``(mean loss s, gradient (dim,))``.
    """
    joint = JointProblem(FIXED, None) if joint is None else joint
    if accel_limit is None:
        accel_limit = _accel_limit(robot, dt)
    values, grads = [], []
    batches = _specs(key, refs, nonideal_refs, steps, temperature, joint, accel_limit, noise)
    for spec, options in batches:
        value, grad = _group_grads(z, spec, joint, robot, dt, options)
        values.append(value)
        grads.append(grad)
    values, grads = jnp.concatenate(values), jnp.concatenate(grads)
    loss, grad, _, _ = capped_mean(values, grads)
    return loss, grad / values.shape[0]


def _step(
    z,
    opt_state,
    key,
    refs,
    nonideal_refs,
    temperature,
    robot,
    dt,
    *,
    steps,
    hyper,
    joint,
    limit,
    noise,
):
    loss, grad = robust_loss(
        z, key, refs, nonideal_refs, temperature, robot, dt, steps, joint, limit, noise
    )
    grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
    updates, opt_state = _optimizer(*hyper).update(grad, opt_state, z)
    return optax.apply_updates(z, updates), opt_state, loss


_step_jit = loops.jit_top_level(
    _step, static_argnames=("steps", "hyper", "joint", "limit", "noise")
)


def _optimizer(learning_rate: float, iters: int) -> optax.GradientTransformation:
    return optimizer(learning_rate, iters)


def robust_score(
    gains: Any,
    refs: Any,
    key: jax.Array,
    *,
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    noise: tuple[float, float] | None = None,
) -> float:
    """Hard-law score: mean arrival over the standard conditions, failures 2× horizon, s.

    The conditions of ``standard_conditions``: the model robot, then
    nominal, latency, noise and both with ±3 % wheel mismatch, on ``robot``
    over its horizon (``robustness.study_horizon``).

    Args:
        gains: ``Gains`` (raw feedback) or a ``ClosedLoop``.
        refs: ``(N, 3)`` reference poses.
        key: the draws' key.
        dt: control period, s.
        robot: the robot; default the one ``gains`` records, else ``Robot()``.
        noise: ``(σ_xy cm, σ_θ degrees)`` of the noise and both conditions;
            default the standard 0.5 cm, 1°.
    """
    if not isinstance(gains, (Gains, ClosedLoop)):
        raise ValueError(
            f"gains = {gains!r:.80} is not allowed; allowed: a wmr_jax.Gains or a ClosedLoop"
        )
    check_key("key", key)
    refs = np.asarray(as_poses("refs", refs, batch=True), dtype=float)
    params = gains.params if isinstance(gains, ClosedLoop) else gains
    require_unbatched(params, "gains", "scalars: one set of gains, scored as one")
    rows = conditions.standard_conditions(
        {"g": gains}, refs, key, dt=dt, x64=False, robot=robot, noise=noise
    )
    return float(np.mean([condition_score(row) for row in rows]))


def condition_score(row: dict[str, Any]) -> float:
    """Mean arrival with failures at twice the horizon, from a ``standard_conditions`` row.

    What the searches minimise per condition, and what the comparison table shows.
    """
    ok = row["success"]
    arrival = row["mean arrival s"] if ok > 0 else 0.0
    return ok * arrival + (1.0 - ok) * _FAILURE_FACTOR * row["horizon s"]


def _black_box(method, key, refs, budget_s, robot, dt, joint, noise=None):
    """Random search or CMA-ES on the logits for ``budget_s`` s: ``(ClosedLoop, candidates)``."""
    start = jnp.asarray(joint.start_logits(robot), float_dtype())
    score_key = jax.random.fold_in(key, 7)

    def closed(z):
        return _concrete(joint.from_logits(z, robot))

    def score(z):
        with warnings.catch_warnings():
            # Candidates far outside the useful set warn; their score says it.
            warnings.simplefilter("ignore")
            return robust_score(closed(z), refs, score_key, dt=dt, robot=robot, noise=noise)

    best = (start, score(start))
    began = time.perf_counter()
    if method == "cma-es":
        from evosax.algorithms import CMA_ES

        strategy = CMA_ES(population_size=8, solution=start)
        params = strategy.default_params
        state = strategy.init(jax.random.fold_in(key, 0), start, params)

    def propose(generation: int) -> Any:
        nonlocal state
        k = jax.random.fold_in(key, generation + 1)
        if method != "cma-es":
            return jax.random.logistic(k, (8, start.shape[0]), float_dtype())
        zs, state = strategy.ask(k, state, params)
        # The strategy broke down (see cma_es_search): keep the best so far.
        return zs if np.all(np.isfinite(np.asarray(zs))) else None

    def tell(generation: int, zs: Any, scores: Any) -> None:
        nonlocal state
        if method == "cma-es":
            k = jax.random.fold_in(key, generation + 1)
            state, _ = strategy.tell(k, zs, scores, state, params)

    def scores(zs: Any) -> jax.Array:
        return jnp.asarray([score(z) for z in zs], float_dtype())

    best_z, _, count = search_loop(
        propose, scores, budget_s, began=began, best=best, count=1, tell=tell,
        at_least_once=False,
    )  # fmt: skip
    return closed(best_z), count


def evosax_available() -> bool:
    """Whether the CMA-ES baseline's library (evosax) can be imported."""
    try:
        import evosax.algorithms  # noqa: F401
    except ImportError:
        return False
    return True


def tune_robust(
    config: RobustConfig | None = None,
    *,
    progress_fn: Any = None,
    on_tuned: Any = None,
    robot: Robot | None = None,
) -> dict[str, Any]:
    """Tune a controller and its estimator through the disturbances; judge with the hard law.

    Args:
        config: the settings; default ``RobustConfig()`` (schedule and EKF).
        progress_fn: called with ``(iteration, loss)`` after each iteration.
        on_tuned: called with ``(ClosedLoop, losses)`` as soon as the
            iterations end, before the searches and the evaluation (which
            take longer than the tuning itself): a caller can keep the result
            from there.
        robot: robot parameters; default ``Robot()``, the paper robot. The
            loop is tuned on it (its wheel budget, its speed limiter where it
            gives acceleration limits) over its horizon
            (``robustness.study_horizon``: 6 s on the paper robot, longer on
            a slower one), and judged, and the searches scored, on it under
            the standard conditions.

    Returns:
        ``{"loop": ClosedLoop (controller, params, estimator, robot), "gains": its
        params, "history": {"loss": (iters,)}, "tune_wall_s": s,
        "searches": {method: (ClosedLoop, candidates)}, "rows":
        standard_conditions rows of the paper's gains (raw feedback; scaled
        into the robot's wheel budget, ``paper_feasible_gains``), the tuned
        loop and the searches' loops, "best_iteration": the iterate kept (the
        lowest ``robust_score`` on the validation poses, the later of equal
        ones; 0 the start), "note": one line if the tuned loop scores no
        better than the paper's gains over the rows' conditions, else None}``.
        ``history`` also holds ``validated_at`` and ``validation`` (s).
    """
    if config is not None and not isinstance(config, RobustConfig):
        raise ValueError(
            f"config = {config!r:.80} is not allowed; allowed: a wmr_jax.tuning.RobustConfig "
            "or None"
        )
    config = (RobustConfig() if config is None else config).validate()
    check_callable("progress_fn", progress_fn)
    check_callable("on_tuned", on_tuned)
    robot = validate_one_robot(robot, "tuning")
    joint = joint_problem(config)
    # The horizon of the studies that judge the loop: on a slower robot the
    # paper's gains, scaled into its budget, need longer (study_horizon).
    horizon = robustness.study_horizon(robot)
    dtype, dt, steps = float_dtype(), DEFAULT_DT, horizon_steps(DEFAULT_DT, horizon)
    limit = _accel_limit(robot, dt)
    noise = config.noise
    z = jnp.asarray(joint.start_logits(robot), dtype)
    hyper = (float(config.learning_rate), int(config.iters))
    opt_state = _optimizer(*hyper).init(z)
    stream = jax.random.fold_in(jax.random.key(config.seed), 11)
    losses, began = [], time.perf_counter()
    validation_refs = sample_poses(
        jax.random.fold_in(jax.random.key(config.seed), 15), config.validation_poses
    )
    validation_key = jax.random.fold_in(jax.random.key(config.seed), 16)

    def scored(iteration: int, z: jax.Array) -> tuple[int, float]:
        with warnings.catch_warnings():
            # An iterate is scored, not reported: its score says what its warnings would.
            warnings.simplefilter("ignore")
            loop_z = _concrete(joint.from_logits(z, robot))
            return iteration, robust_score(
                loop_z, validation_refs, validation_key, robot=robot, noise=noise
            )

    validated, iterates = [scored(0, z)], {0: z}
    for i in range(config.iters):
        temp = anneal(config.temperature_start, config.temperature_end, i, config.iters)
        k = jax.random.fold_in(stream, i)
        k_refs, k_ni, k_dist = jax.random.split(k, 3)
        refs = sample_poses(k_refs, config.poses)
        ni_refs = sample_poses(k_ni, config.nonideal_poses)
        z, opt_state, loss = _step_jit(
            z, opt_state, k_dist, refs, ni_refs, jnp.asarray(temp, dtype), robot,
            jnp.asarray(dt, dtype), steps=steps, hyper=hyper, joint=joint, limit=limit,
            noise=noise if config.around is None else config.around,
        )  # fmt: skip
        losses.append(float(loss))
        if (i + 1) % config.validate_every == 0 or i + 1 == config.iters:
            validated.append(scored(i + 1, z))
            iterates[i + 1] = z
        if progress_fn is not None:
            progress_fn(i + 1, losses[-1])
    wall = time.perf_counter() - began
    best = best_iteration(validated)
    tuned = _concrete(joint.from_logits(iterates[best], robot))._replace(robot=robot)
    if on_tuned is not None:
        on_tuned(tuned, list(losses))
    sets = {"paper": paper_feasible_gains(robot), "robust-tuned": tuned}
    searches = {}
    if config.compare:
        search_refs = sample_poses(jax.random.fold_in(stream, -1 % 2**31), config.search_poses)
        for method in ("random search", "cma-es"):
            if method == "cma-es" and not evosax_available():
                continue
            key = jax.random.fold_in(jax.random.key(config.seed), 12 + len(searches))
            searches[method] = _black_box(method, key, search_refs, wall, robot, dt, joint, noise)
            sets[method] = searches[method][0]
    held_out = held_out_poses(config.eval_poses, EVAL_SEED)
    # The noise of wmr-jax robustness at its default seed: the same table.
    rows = conditions.standard_conditions(
        sets, held_out, jax.random.key(EVAL_NOISE_SEED), robot=robot, noise=noise
    )
    means = {
        name: float(np.mean([condition_score(r) for r in rows if r["gains"] == name]))
        for name in ("paper", "robust-tuned")
    }
    note = None
    if means["robust-tuned"] >= means["paper"]:
        note = (
            "warning: the tuned loop is no better than the baseline (paper): score "
            f"{means['robust-tuned']:.3f} s against {means['paper']:.3f} s over the standard "
            "conditions on the held-out poses"
        )
    return {
        "loop": tuned,
        "gains": tuned.params,
        "history": {
            "loss": np.asarray(losses),
            "validated_at": np.asarray([i for i, _ in validated], dtype=int),
            "validation": np.asarray([v for _, v in validated], dtype=float),
        },
        "tune_wall_s": wall,
        "searches": searches,
        "rows": rows,
        "best_iteration": best,
        "note": note,
    }
