"""Robust tuning: controller and estimator tuned together (docs/model.md §7, §9).

The loss is the relaxed arrival time averaged over domain-randomised runs
(``sample_conditions``); ``tune_robust`` also runs the black-box searches for the
same compute (``black_box``, ``iteration_price``) and judges all with the hard law.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

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
from wmr_jax._src.model.controllers.schedule import KNOTS
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.poses import horizon_steps, sample_poses
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.sim.sensing import disturbances, loop
from wmr_jax._src.sim.sensing.estimators import BUILT_IN, OBSERVER_KNOTS
from wmr_jax._src.sim.sensing.loop import ClosedLoop
from wmr_jax._src.studies import conditions, robustness
from wmr_jax._src.tuning import centred, trainer
from wmr_jax._src.tuning.estimation import JointProblem, concrete_loop, estimator_box
from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED, held_out_poses, quiet_scoring
from wmr_jax._src.tuning.loss import capped_mean, recorded_arrival
from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
from wmr_jax._src.tuning.problems import FIXED, schedule_problem
from wmr_jax._src.tuning.search import (
    FAILURE_FACTOR,
    clock,
    cma_es_proposals,
    evosax_available,
    robust_population_scores,
    search_loop,
)
from wmr_jax._src.tuning.trainer import TrainState, TuneResult

# Seed of the noise the standard conditions are judged under: that of
# ``wmr-jax robustness`` at its default ``--seed``, so both write the same table.
EVAL_NOISE_SEED = 0

TUNERS = ("gradient", "hybrid")
GENERATION = 8  # candidates per black-box generation, one batch each
_NOISE_LEVEL_MAX = 2.0  # training noise up to twice the sensor's level
# The standard pose noise (σ_xy cm, σ_θ degrees): that of the noisy standard conditions.
_STANDARD_NOISE = next((c[1], c[2]) for c in disturbances.STANDARD_CONDITIONS if c[1])


@dataclasses.dataclass(frozen=True)
class RobustConfig:
    """Settings of ``tune_robust``; the loop's fields as ``TuneConfig`` names them.

    Attributes:
        iters, seed, learning_rate, temperature_start, temperature_end,
        eval_poses, validate_every, validation_poses: as ``TuneConfig``'s;
            the validation score is ``robust_score`` under the standard conditions.
        poses: reference poses per standard condition per iteration (ideal loop).
        nonideal_poses: poses of the randomised non-ideal group per iteration (0: none).
        search_poses: poses per condition that random search and CMA-ES score on.
        compare: also run random search and CMA-ES, each scoring as many
            candidates as the tuning's compute buys (``iteration_price``).
        price: with ``compare``, the candidates one iteration is worth in the
            searches' budget (``None``: measured, ``iteration_price``; a recorded
            one gives the same budget on any machine).
        law: ``"schedule"`` (the gain schedule) or ``"fixed"`` (the 7 gains).
        estimator: ``"ekf"``, ``"observer"``, or ``None`` (raw feedback),
            tuned together with the controller.
        knots, observer_knots: knots per table of the schedule, of the observer.
        noise_xy: the sensor's position noise σ_xy, cm: the training draws up to
            twice it per run; the validation, searches and evaluation judge at it.
        noise_theta: the sensor's heading noise σ_θ, degrees (as ``noise_xy``).
        around: ``centred.Centred`` ranges of an identified robot that the
            training draws its runs from (``centred.for_config``); ``None``:
            the standard conditions.
        tuner: ``"gradient"``: the gradient iterations alone; ``"hybrid"``:
            then CMA-ES from their result on the hard-law score (``black_box``).
        polish_share: the polish's share of the hybrid's CPU time
            (``search.clock``), in (0, 1): it runs for
            ``share / (1 − share)`` times the iterations' CPU time.
        polish_std: the polish's CMA-ES step in logits.
    """

    problem: ClassVar[str] = "robust"

    # choice: 600 iterations, not 300 (docs/robustness.md).
    iters: int = 600
    poses: int = 32
    nonideal_poses: int = 8
    seed: int = 0
    learning_rate: float = 0.1
    temperature_start: float = 0.1
    temperature_end: float = 0.003
    eval_poses: int = EVAL_POSES
    search_poses: int = 32
    compare: bool = False
    price: float | None = None
    law: str = "schedule"
    estimator: str | None = "ekf"
    knots: int = KNOTS
    observer_knots: int = OBSERVER_KNOTS
    validate_every: int = 25
    validation_poses: int = 32
    noise_xy: float = 0.5
    noise_theta: float = 1.0
    around: centred.Centred | None = None
    tuner: str = "gradient"
    polish_share: float = 0.5
    polish_std: float = 0.1

    def validate(self) -> RobustConfig:
        """Check every field; return ``self`` (``ValueError`` naming the field)."""
        trainer.check_loop(self)
        check_int("nonideal_poses", self.nonideal_poses, 0)
        check_int("search_poses", self.search_poses, 1)
        check_bool("compare", self.compare)
        if self.price is not None:
            check_number("price", self.price, unit="candidates per iteration")
        check_number("noise_xy", self.noise_xy, closed=True, unit="cm")
        check_number("noise_theta", self.noise_theta, closed=True, unit="degrees")
        if self.tuner not in TUNERS:
            raise ValueError(
                f"tuner = {self.tuner!r} is not allowed; allowed: 'gradient' or 'hybrid'"
            )
        check_number("polish_share", self.polish_share, high=1.0)
        check_number("polish_std", self.polish_std)
        if self.tuner == "hybrid" and not evosax_available():
            raise ValueError(
                "tuner = 'hybrid' polishes with CMA-ES, which needs evosax; allowed: "
                "pip install 'wmr-jax[search]', or tuner = 'gradient'"
            )
        if self.law not in ("fixed", "schedule"):
            raise ValueError(f"law = {self.law!r} is not allowed; allowed: 'fixed' or 'schedule'")
        if self.estimator is not None and self.estimator not in BUILT_IN:
            raise ValueError(
                f"estimator = {self.estimator!r} is not allowed; allowed: None, "
                f"{', '.join(repr(n) for n in BUILT_IN)}"
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

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as JSON-ready values."""
        return dataclasses.asdict(self)


def joint_problem(config: RobustConfig) -> JointProblem:
    """The ``JointProblem`` that ``config`` tunes."""
    problem = FIXED if config.law == "fixed" else schedule_problem(config.knots)
    box = None
    if config.estimator is not None:
        box = estimator_box(config.estimator, config.observer_knots)
    return JointProblem(problem, box)


def _runs(gradient, z, key, refs, nonideal_refs, temperature, robot, dt, steps, joint, *rest):
    """Per-run losses ``(N,)`` of ``sample_conditions``' draw; with ``gradient``, and ``(N, dim)``.

    ``*rest``: ``accel_limit``, ``noise`` and ``law_derivative`` of ``sample_conditions``.
    """
    init = jnp.zeros((3,), dt.dtype)
    parts = []
    for spec, options in sample_conditions(
        key, refs, nonideal_refs, steps, temperature, joint, *rest
    ):  # fmt: skip

        def run_loss(z, spec, options=options):
            closed = joint.from_logits(z, robot)
            _, _, (poses, _, _) = loop.disturbed_run(
                spec, closed.params, init, robot, dt, options, estimate=closed.estimator,
                record=True,
            )  # fmt: skip
            return recorded_arrival(poses, spec.ref, dt)

        run = jax.value_and_grad(run_loss) if gradient else run_loss
        parts.append(jax.vmap(run, in_axes=(None, disturbances.Disturbance(0, 0, 0, 0)))(z, spec))
    return jax.tree.map(lambda *leaves: jnp.concatenate(leaves), *parts)


def robust_loss_value(*args):
    """``RobustLoss``'s mean without its gradient, s; ``*args`` as ``_runs``' after ``gradient``."""
    return jnp.mean(_runs(False, *args))


def sample_conditions(
    key, refs, nonideal_refs, steps, temperature, joint, accel_limit=False, noise=None,
    law_derivative="traced",
):  # fmt: skip
    """The conditions the robust loss trains under: ``[(disturbances, options)]`` from ``key``.

    ``refs`` under each standard condition with wheel mismatch, in the ideal
    loop (one batch), and ``nonideal_refs`` (may be empty) under mass
    mismatch and latency besides, in the non-ideal loop. The noise
    ``(σ_xy cm, σ_θ degrees)`` (default the standard 0.5 cm, 1°) is scaled
    per run by a level ``U(0, 2)``; a ``centred.Centred`` draws every run
    from its ranges instead. ``accel_limit``, ``law_derivative``: as ``RobustLoss``'s.
    """
    keys = jax.random.split(key, 2 * len(disturbances.STANDARD_CONDITIONS) + 1)
    ideal = loops.Options(
        steps=steps,
        controller=joint.problem.controller,
        temperature=temperature,
        estimator=joint.options_estimator,
        accel_limit=accel_limit,
        law_derivative=law_derivative,
    )
    if isinstance(noise, centred.Centred):  # around an identified robot (RobustConfig.around)
        return centred.batches(key, refs, nonideal_refs, steps, ideal, noise)
    noise_xy, noise_deg = _STANDARD_NOISE if noise is None else noise

    def drawn(k_level, k_spec, at, sxy, sdeg, latency, mass=0.0):
        level = jax.random.uniform(k_level, at.shape[:1], refs.dtype, 0.0, _NOISE_LEVEL_MAX)
        return disturbances.sample_disturbance(
            k_spec,
            at,
            steps,
            noise_xy=sxy * level,
            noise_theta=math.radians(sdeg) * level,
            latency=float(latency),
            radius_mismatch=disturbances.STANDARD_MISMATCH,
            mass_mismatch=mass,
        )

    specs = [
        drawn(
            keys[2 * i],
            keys[2 * i + 1],
            refs,
            *((noise_xy, noise_deg) if sxy else (sxy, sdeg)),
            latency,
        )
        for i, (_, sxy, sdeg, latency) in enumerate(disturbances.STANDARD_CONDITIONS)
    ]
    # One batch for all conditions: one scan to compile, not four.
    batches = [(jax.tree.map(lambda *leaves: jnp.concatenate(leaves), *specs), ideal)]
    if nonideal_refs.shape[0]:
        spec = drawn(*jax.random.split(keys[-1]), nonideal_refs, noise_xy, noise_deg, 0.5, 0.2)
        nonideal = dataclasses.replace(ideal, velocity="nonideal", accel_limit=False)
        batches.append((spec, nonideal))
    return batches


def robust_score(
    gains: Any,
    refs: Any,
    key: jax.Array,
    *,
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    noise: tuple[float, float] | None = None,
) -> float:
    """Hard-law score: mean arrival over the ``standard_conditions``, failures 2× horizon, s.

    Args:
        gains: ``Gains`` (raw feedback) or a ``ClosedLoop``.
        refs: ``(N, 3)`` reference poses.
        key: the draws' key.
        dt: control period, s.
        robot: the robot, run over its horizon; default the one ``gains``
            records, else ``Robot()``.
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
    """Mean arrival with failures at twice the horizon, from a ``standard_conditions`` row."""
    ok = row["success"]
    arrival = row["mean arrival s"] if ok > 0 else 0.0
    return ok * arrival + (1.0 - ok) * FAILURE_FACTOR * row["horizon s"]


@dataclasses.dataclass(frozen=True)
class RobustLoss:
    """The robust tuning loss of one iteration (``TrainingProblem.loss``), hashable.

    ``self(z, (key, refs, nonideal_refs), temperature, (robot, dt))``: the mean
    loss over the runs of ``sample_conditions`` and its ``capped_mean`` gradient ``(dim,)``.

    Attributes:
        steps: control periods per run.
        joint: the ``JointProblem`` of ``z``.
        accel_limit: the ideal loop's speed limiter (docs/model.md §4.2.2).
        noise: ``(σ_xy cm, σ_θ degrees)`` of the sensor (``RobustConfig.noise``;
            ``None``: the standard 0.5 cm, 1°), or a ``centred.Centred`` whose
            ranges every run is drawn from (``RobustConfig.around``).
        law_derivative: ``loops.Options.law_derivative`` of every run (docs/robustness.md).
    """

    steps: int
    joint: JointProblem
    accel_limit: bool
    noise: tuple[float, float] | centred.Centred | None
    law_derivative: str = "traced"

    def __post_init__(self):
        if self.law_derivative not in loops.LAW_DERIVATIVES:
            allowed = " or ".join(map(repr, loops.LAW_DERIVATIVES))
            raise ValueError(
                f"law_derivative = {self.law_derivative!r:.40} is not allowed; allowed: {allowed}"
            )

    def __call__(self, z, batch, temperature, consts):
        key, refs, nonideal_refs = batch
        robot, dt = consts
        values, grads = _runs(
            True, z, key, refs, nonideal_refs, temperature, robot, dt, self.steps, self.joint,
            self.accel_limit, self.noise, self.law_derivative,
        )  # fmt: skip
        loss, grad, _, _ = capped_mean(values, grads)
        grad = grad / values.shape[0]
        return loss, jnp.where(jnp.isfinite(grad), grad, 0.0)


def robust_problem(config: RobustConfig, robot: Robot) -> trainer.TrainingProblem:
    """The ``TrainingProblem`` of a checked ``config`` on a checked ``robot``.

    A draw is ``(key of the disturbances, refs, nonideal_refs)``; a row is
    the loop's parameters and its estimator's, flattened.
    """
    joint = joint_problem(config)
    horizon = robustness.study_horizon(robot)
    dtype, dt = float_dtype(), DEFAULT_DT
    seed = jax.random.key(config.seed)
    stream = jax.random.fold_in(seed, 11)
    validation_refs = sample_poses(jax.random.fold_in(seed, 15), config.validation_poses)
    validation_key = jax.random.fold_in(seed, 16)
    z0 = jnp.asarray(joint.start_logits(robot), dtype)
    start = concrete_loop(joint.from_logits(z0, robot))
    treedef = jax.tree.structure((start.params, start.estimator))

    def batch(iteration: int) -> tuple:
        k_refs, k_ni, k_dist = jax.random.split(jax.random.fold_in(stream, iteration), 3)
        return k_dist, sample_poses(k_refs, config.poses), sample_poses(k_ni, config.nonideal_poses)

    def row(z: Any) -> tuple[float, ...]:
        closed = concrete_loop(joint.from_logits(z, robot))
        return tuple(jax.tree.leaves((closed.params, closed.estimator)))

    def from_row(values: Any) -> ClosedLoop:
        params, estimate = jax.tree.unflatten(treedef, [float(v) for v in values])
        return ClosedLoop(joint.problem.controller, params, estimate)

    def score(closed: ClosedLoop) -> float:
        with quiet_scoring():
            return robust_score(
                closed, validation_refs, validation_key, robot=robot, noise=config.noise
            )

    return trainer.TrainingProblem(
        name="robust",
        z0=z0,
        loss=RobustLoss(
            horizon_steps(dt, horizon),
            joint,
            loops.for_robot(loops.Options(), robot, dt).accel_limit,
            config.noise if config.around is None else config.around,
        ),
        consts=(robot, jnp.asarray(dt, dtype)),
        batch=batch,
        row=row,
        from_row=from_row,
        score=score,
        hyper=trainer.Hyper(float(config.learning_rate), int(config.iters)),
        temperature_start=config.temperature_start,
        temperature_end=config.temperature_end,
        validate_every=config.validate_every,
    )


def _scorer(refs, key, robot, dt, joint, noise):
    """``scores(zs)``: ``robust_score`` of each row of logits ``zs (P, dim)``, s."""

    def scores(zs: Any) -> np.ndarray:
        with quiet_scoring():
            loops = [concrete_loop(joint.from_logits(z, robot)) for z in zs]
            return robust_population_scores(loops, refs, key, dt=dt, robot=robot, noise=noise)

    return scores


def iteration_price(problem, state, scores, rounds=5):
    """Candidates one gradient iteration costs: its CPU time over one candidate's scoring.

    A compiled iteration (``trainer.train_step`` at ``state``) and the scoring
    of a generation (``scores``) are timed in turn, ``rounds`` times each
    after compiling, so that the machine's load falls on both alike; the
    ratio of the medians.
    """
    dtype = float_dtype()
    temperature = jnp.asarray(problem.temperature_end, dtype)
    generation = jnp.broadcast_to(state.z, (GENERATION, state.z.shape[0]))

    def iteration():
        out = trainer.train_step(
            state.z, state.opt_state, problem.batch(0), temperature, problem.consts,
            loss=problem.loss, hyper=problem.hyper,
        )  # fmt: skip
        jax.block_until_ready(out)

    iteration()
    scores(generation)
    per_iteration, per_generation = [], []
    for _ in range(rounds):
        began = clock()
        iteration()
        per_iteration.append(clock() - began)
        began = clock()
        scores(generation)
        per_generation.append(clock() - began)
    return float(np.median(per_iteration) / (np.median(per_generation) / len(generation)))


def black_box(
    method, key, refs, budget_s, robot, dt, joint, noise=None, *, start=None, std=1.0,
    candidates=None,
):  # fmt: skip
    """Random search or CMA-ES on the logits for ``budget_s`` CPU seconds (``search.clock``).

    ``GENERATION`` candidates per generation (random search: uniform in the
    cube), scored by ``robust_score`` on ``refs`` under the same draws; the
    start (default the problem's; CMA-ES's mean, step ``std``) is scored first,
    in the budget. ``candidates``: a budget in candidates instead of ``budget_s``.

    Returns:
        ``(ClosedLoop, candidates scored, CPU s, wall s)``.
    """
    wall, began = time.perf_counter(), clock()
    start = joint.start_logits(robot) if start is None else start
    start = jnp.asarray(start, float_dtype())
    score_key = jax.random.fold_in(key, 7)

    scores = _scorer(refs, score_key, robot, dt, joint, noise)
    best = (start, float(scores(start[None])[0]))
    tell = None
    if method == "cma-es":
        propose, tell = cma_es_proposals(key, start, GENERATION, std, split=False)
    else:

        def propose(generation: int) -> Any:
            k = jax.random.fold_in(key, generation + 1)
            return jax.random.logistic(k, (GENERATION, start.shape[0]), float_dtype())

    best_z, _, count = search_loop(
        propose, scores, budget_s, began=began, best=best, count=1, tell=tell,
        at_least_once=False, max_count=candidates,
    )  # fmt: skip
    loop = concrete_loop(joint.from_logits(best_z, robot))
    return loop, count, clock() - began, time.perf_counter() - wall


def search_poses(config: RobustConfig) -> jax.Array:
    """The poses the searches of ``config``'s seed score candidates on, ``(search_poses, 3)``."""
    stream = jax.random.fold_in(jax.random.key(config.seed), 11)
    return sample_poses(jax.random.fold_in(stream, -1 % 2**31), config.search_poses)


def compared_search(method: str, config: RobustConfig, robot: Robot, candidates: int) -> tuple:
    """A search of ``tune_robust``'s comparison: ``black_box`` at a budget of ``candidates``."""
    key = jax.random.fold_in(jax.random.key(config.seed), 12 + (method == "cma-es"))
    joint = joint_problem(config)
    return black_box(
        method, key, search_poses(config), math.inf, robot, DEFAULT_DT, joint, config.noise,
        candidates=candidates,
    )  # fmt: skip


def tune_robust(
    config: RobustConfig | None = None,
    *,
    robot: Robot | None = None,
    state: TrainState | None = None,
    progress_fn: Any = None,
    on_tuned: Any = None,
) -> TuneResult:
    """Tune a controller and its estimator through the disturbances; judge with the hard law.

    Args:
        config: the settings; default ``RobustConfig()`` (schedule and EKF, no searches).
        robot: robot parameters; default the paper robot. The loop is tuned on
            it (wheel budget, speed limiter) over its horizon
            (``robustness.study_horizon``), and judged, and searched, there.
        state: continue from this ``TrainState`` (from ``progress_fn`` of a run
            of the same ``config`` and ``robot``).
        progress_fn: called with the ``TrainState`` after each iteration.
        on_tuned: called with ``(ClosedLoop, losses)`` once the loop is
            tuned, before the searches and the evaluation.

    Returns:
        A ``TuneResult`` of problem ``"robust"`` (its fields say what the
        robust problem fills in); ``tune_cpu_s`` counts the polish too.
    """
    config = trainer.checked_config(config, RobustConfig)
    check_callable("progress_fn", progress_fn)
    trainer.check_state(state)
    check_callable("on_tuned", on_tuned)
    robot = validate_one_robot(robot, "tuning")
    problem, run = robust_problem(config, robot), trainer.run_text(config, robot)
    tuned, best, history, state = trainer.fit(problem, run, state, progress_fn)
    tuned, cpu = tuned._replace(robot=robot), state.elapsed_s
    joint, dt = joint_problem(config), DEFAULT_DT
    search_refs = search_poses(config)
    polished = 0
    if config.tuner == "hybrid":
        # CMA-ES on the hard-law score from the kept iterate (the last, or the
        # lowest scored), scored first so never worse on the search poses.
        start = state.z if best == state.iteration else state.lowest_z
        share, began = config.polish_share, clock()
        tuned, polished, *_ = black_box(
            "cma-es", jax.random.fold_in(jax.random.key(config.seed), 20), search_refs,
            cpu * share / (1.0 - share), robot, dt, joint, config.noise, start=start,
            std=config.polish_std,
        )  # fmt: skip
        tuned, cpu = tuned._replace(robot=robot), cpu + clock() - began
    if on_tuned is not None:
        on_tuned(tuned, list(state.losses))
    sets = {"paper": paper_feasible_gains(robot), "robust-tuned": tuned}
    searches, budget = {}, None
    if config.compare:
        # Equal compute: as many candidates as the gradient's iterations (at
        # the measured or given price), its validations and polish.
        measured = iteration_price(
            problem, state, _scorer(search_refs, jax.random.key(0), robot, dt, joint, config.noise)
        )  # fmt: skip
        price = measured if config.price is None else config.price
        validated = len(state.validated) * config.validation_poses / config.search_poses
        candidates = max(1, round(state.iteration * price + validated + polished))
        budget = {"price": price, "measured_price": measured, "candidates": candidates}
        for method in ("random search", "cma-es"):
            if method == "cma-es" and not evosax_available():
                continue
            searches[method] = compared_search(method, config, robot, candidates)
            sets[method] = searches[method][0]
    held_out = held_out_poses(config.eval_poses, EVAL_SEED)
    rows = conditions.standard_conditions(
        sets, held_out, jax.random.key(EVAL_NOISE_SEED), robot=robot, noise=config.noise
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
    return TuneResult(
        tuned.params, {}, history, cpu, None, "robust", best, note, tuned, rows, searches, budget
    )
