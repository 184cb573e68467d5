"""The tuner: Adam on the logits of the feasible set, with an annealed smooth law.

``train`` starts from the paper's feasible gains (``PAPER_FEASIBLE_GAINS``,
moved just inside the search box, whose budget is the robot's), runs ``config.iters`` iterations of
``optax.chain(clip_by_global_norm, adam)`` on the robust batch gradient of
``tuning_loss`` over a fresh batch of ``config.poses`` references each,
annealing the smooth law's temperature, and then, with the hard law, runs
``random_search`` for the same wall time and evaluates the paper's, the
tuned and the random search's gains on held-out poses.

Like brax's ``train``, it reports through a callback and returns a result:
``progress_fn(state)`` is called after every iteration with a ``TrainState``
that holds everything needed to continue (``state=``) from there, bit for
bit. It writes no files; ``wmr-jax tune`` checkpoints from the callback.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from wmr_jax._src.checks import (
    as_float_tree,
    check_bool,
    check_callable,
    check_int,
    check_number,
    float_dtype,
)
from wmr_jax._src.model.controllers.schedule import KNOTS
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.provenance import code_version
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R, DEFAULT_TOL_THETA
from wmr_jax._src.sim.poses import HORIZON_S, MAX_SAMPLES, sample_poses
from wmr_jax._src.tuning.evaluation import (
    EVAL_POSES,
    EVAL_SEED,
    RUN_OPTIONS,
    Evaluation,
    evaluate,
    hard_runs,
    held_out_poses,
)
from wmr_jax._src.tuning.loss import LossSpec, LossWeights, make_spec, robust_value_and_grad
from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
from wmr_jax._src.tuning.problems import FIXED, MAX_TUNED_KNOTS, Problem, schedule_problem
from wmr_jax._src.tuning.search import FAILURE_FACTOR, SearchResult, random_search

__all__ = [
    "TrainState",
    "TuneConfig",
    "TuneResult",
    "init_state",
    "restore_state",
    "differences",
    "run_identity",
    "state_arrays",
    "train",
    "training_poses",
]


@dataclasses.dataclass(frozen=True)
class _OptimHyper:
    """Static optimiser settings (part of the train step's compile key)."""

    learning_rate: float
    iters: int
    grad_clip: float
    pose_clip: float | None


# The gain schedule's settings where they differ from the fixed gains'. Its
# 35 parameters need more and longer steps than seven (held-out poses, seed 0:
# 400 iterations at 0.1 reach 0.45 s, 600 or 800 at 0.2 reach 0.41 s), and
# annealing the law down to T = 0.003 rather than 0.01 shortens the tuned
# arrival by another 0.008 s (1,000 validation poses of seed 777, not the
# held-out set: 0.428 -> 0.419 s, mean of training seeds 0-2; for the fixed
# gains it changes nothing, 0.607 -> 0.606 s).
SCHEDULE_SETTINGS = {"iters": 600, "learning_rate": 0.2, "temperature_end": 0.003}


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Everything that decides the result of ``train`` (saved with each checkpoint).

    Attributes:
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (``docs/model.md §4``).
        iters: Adam iterations.
        poses: reference poses per iteration, a fresh batch each time
            (``docs/model.md §6``).
        seed: seed of the training poses and of the random search.
        learning_rate: Adam's initial step in logit space (cosine-decayed).
        grad_clip: ``clip_by_global_norm`` threshold of the batch gradient.
        pose_clip: cap of each pose's gradient norm, in multiples of the
            batch median; ``None`` for a plain mean.
        temperature_start: smooth-law temperature of the first iteration.
        temperature_end: temperature of the last (annealed geometrically).
        horizon: simulated time per run, s.
        dt: control period, s.
        checkpoint_every: iterations between checkpoints (of ``wmr-jax tune``).
        eval_poses: held-out poses of the before/after table.
        eval_seed: seed of the held-out poses (the same for every ``seed``).
        random_search: also run random search for the tuning's wall time.
        weights: terms of the loss (see ``tuning_loss``).
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        schedule: tune the gain-scheduled law (``ScheduleParams``, 35
            parameters) instead of the seven fixed gains.
        knots: knots per table of the schedule (``3 knots + 5`` parameters;
            schedules only).
        validate_every: iterations between hard-law scores of the iterate
            on the validation poses; the start and the last iterate are
            always scored, and the best scored iterate is the result.
        validation_poses: poses of that score, drawn from ``seed`` apart
            from the training batches and the held-out poses.
    """

    velocity: str = "ideal"
    iters: int = 400
    poses: int = 256
    seed: int = 0
    learning_rate: float = 0.1
    grad_clip: float = 1.0
    pose_clip: float | None = 1.0
    temperature_start: float = 0.1
    temperature_end: float = 0.01
    horizon: float = HORIZON_S
    dt: float = simulation.DEFAULT_DT
    checkpoint_every: int = 25
    eval_poses: int = EVAL_POSES
    eval_seed: int = EVAL_SEED
    random_search: bool = True
    weights: LossWeights = LossWeights()
    substeps: int = loops.DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"
    schedule: bool = False
    knots: int = KNOTS
    validate_every: int = 25
    validation_poses: int = 128

    @classmethod
    def for_problem(cls, problem: str = "fixed", **changes: Any) -> TuneConfig:
        """The recommended settings of ``problem``, with ``changes`` on top.

        ``"fixed"`` is ``TuneConfig()``; ``"schedule"`` also sets
        ``schedule=True`` and ``SCHEDULE_SETTINGS`` (600 iterations, a step
        of 0.2, the law annealed to T = 0.003), which ``wmr-jax tune
        --schedule`` and ``compare`` use.

        Raises:
            ValueError: for another ``problem``, naming it.
        """
        problem = getattr(problem, "name", problem)  # a Problem, or its name
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"{unknown[0]!r} is not allowed; allowed: the fields of TuneConfig")
        if problem == "fixed":
            return cls(**changes)
        if problem == "schedule":
            return cls(**{"schedule": True, **SCHEDULE_SETTINGS, **changes})
        raise ValueError(f"problem = {problem!r} is not allowed; allowed: 'fixed', 'schedule'")

    @property
    def problem(self) -> Problem:
        """The tuning problem: gain schedules of ``knots`` if ``schedule``, else fixed gains."""
        return schedule_problem(self.knots) if self.schedule else FIXED

    def replace(self, **changes: Any) -> TuneConfig:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)

    def validate(self) -> TuneConfig:
        """Check every field; return ``self``.

        Raises:
            ValueError: naming the field, its value and what is allowed.
        """
        for name, minimum, maximum in _INT_FIELDS:
            check_int(name, getattr(self, name), minimum, maximum)
        for name in _POSITIVE_FIELDS:
            check_number(name, getattr(self, name))
        for name in ("temperature_start", "temperature_end"):
            simulation.check_temperature(name, getattr(self, name))
        if self.pose_clip is not None:
            check_number("pose_clip", self.pose_clip)
        for name in ("random_search", "schedule"):
            check_bool(name, getattr(self, name))
        if not self.schedule and self.knots != KNOTS:
            raise ValueError(
                f"knots = {self.knots!r} is not allowed with schedule = False; allowed: knots "
                "for a gain schedule only (TuneConfig.for_problem('schedule', knots=...))"
            )
        self.spec()
        return self

    def spec(self) -> LossSpec:
        """The static loss settings of this configuration (checked)."""
        return make_spec(
            horizon=self.horizon,
            dt=self.dt,
            velocity=self.velocity,
            substeps=self.substeps,
            wheel_limit=self.wheel_limit,
            tol_r=DEFAULT_TOL_R,
            tol_theta=DEFAULT_TOL_THETA,
            weights=self.weights,
            remat=True,
            controller=self.problem.controller,
        )

    def hyper(self) -> _OptimHyper:
        """The static optimiser settings of this configuration."""
        pose_clip = None if self.pose_clip is None else float(self.pose_clip)
        return _OptimHyper(
            float(self.learning_rate), int(self.iters), float(self.grad_clip), pose_clip
        )

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as JSON-ready values."""
        out = dataclasses.asdict(self)
        out["weights"] = dataclasses.asdict(self.weights)
        return out


# name, minimum, maximum of the integer fields of TuneConfig.
_INT_FIELDS = (
    ("iters", 1, None),
    ("poses", 1, MAX_SAMPLES),
    ("seed", 0, 2**32 - 1),
    ("checkpoint_every", 1, None),
    ("eval_poses", 1, MAX_SAMPLES),
    ("eval_seed", 0, 2**32 - 1),
    ("knots", 2, MAX_TUNED_KNOTS),
    ("validate_every", 1, None),
    ("validation_poses", 1, MAX_SAMPLES),
)
_POSITIVE_FIELDS = ("learning_rate", "grad_clip", "temperature_start", "temperature_end")


class TrainState(NamedTuple):
    """The whole state of a tuning run after ``iteration`` iterations.

    Attributes:
        iteration: iterations done.
        z: ``(dim,)`` logits of the current parameters (``Problem.from_logits``).
        opt_state: the optax state.
        losses: loss of each iteration done, s.
        temperatures: smooth-law temperature of each iteration done.
        gains: the parameters after each iteration, as flat rows (``Problem.columns``).
        elapsed_s: wall time of the iterations done (all sessions), s.
        run: the ``run_identity`` of the settings and robot it belongs to, as
            JSON text; ``train`` refuses a state of another run. Empty: not
            recorded (a state built by hand), then not checked.
        validated: ``(iteration, score s)`` of each hard-law score on the
            validation poses so far (iteration 0: the start), in order.
        start: the start's parameters as a flat row (``Problem.columns``).
    """

    iteration: int
    z: jax.Array
    opt_state: Any
    losses: tuple[float, ...]
    temperatures: tuple[float, ...]
    gains: tuple[tuple[float, ...], ...]
    elapsed_s: float
    run: str = ""
    validated: tuple[tuple[int, float], ...] = ()
    start: tuple[float, ...] = ()


class TuneResult(NamedTuple):
    """What ``train`` returns.

    Attributes:
        gains: the tuned parameters (feasible; floats): ``Gains``, or
            ``ScheduleParams`` for a schedule.
        evaluation: hard-law ``Evaluation`` on the held-out poses, keyed
            ``"paper_feasible"`` (``paper_feasible_gains(robot)``), ``"tuned"``
            and, if run, ``"random_search"``.
        history: per-iteration ``loss`` (s), ``temperature`` and ``gains``
            ``(iters, columns)`` (``Problem.columns``), and the validation
            scores: ``validated_at`` (iterations, 0 the start) and
            ``validation`` (s), as NumPy arrays.
        tune_wall_s: wall time of the gradient iterations (all sessions), s.
        search: the random search's result, or ``None``.
        problem: ``"fixed"`` or ``"schedule"``.
        best_iteration: the iterate returned (0: the start): the last,
            unless an earlier one has a validation score lower by more than
            ``BEST_MARGIN``; then the lowest, the later of equal ones.
        note: one line when the tuned parameters are no better than the
            baseline on the held-out poses (``no_better_than_baseline``),
            else ``None``.
    """

    gains: Gains
    evaluation: dict[str, Evaluation]
    history: dict[str, np.ndarray]
    tune_wall_s: float
    search: SearchResult | None
    problem: str = "fixed"
    best_iteration: int = 0
    note: str | None = None


# ---------------------------------------------------------------- optimiser


def optimizer(
    learning_rate: float, iters: int, grad_clip: float = 1.0
) -> optax.GradientTransformation:
    """The tuners' optimiser: ``clip_by_global_norm`` then Adam, its step cosine-decayed.

    Cosine decay to a tenth: large steps while the temperature is high and
    the landscape smooth, small ones once it is close to the hard law. The
    fixed-gain and schedule tuner (``train``) and the robust one
    (``tune_robust``) share it.
    """
    schedule = optax.cosine_decay_schedule(learning_rate, iters, alpha=0.1)
    return optax.chain(optax.clip_by_global_norm(grad_clip), optax.adam(schedule))


def anneal(start: float, end: float, iteration: int, iters: int) -> float:
    """The smooth law's temperature, geometric: ``start`` at 0, ``end`` at ``iters − 1``.

    The one schedule of both tuners.
    """
    frac = iteration / max(iters - 1, 1)
    return start * (end / start) ** frac


def _optimizer(hyper: _OptimHyper) -> optax.GradientTransformation:
    return optimizer(hyper.learning_rate, hyper.iters, hyper.grad_clip)


def _train_step(z, opt_state, refs, temperature, init, robot, dt, *, spec, hyper, problem):
    loss, grad, stats = robust_value_and_grad(
        z, refs, init, robot, dt, spec, temperature, hyper.pose_clip, problem
    )
    updates, opt_state = _optimizer(hyper).update(grad, opt_state, z)
    # Feasibility needs no projection: every z maps into the feasible set.
    z = optax.apply_updates(z, updates)
    stats = dict(stats, grad_norm=jnp.linalg.norm(grad))
    return z, opt_state, loss, stats


_train_step_jit = loops.jit_top_level(_train_step, static_argnames=("spec", "hyper", "problem"))


def _temperature(config: TuneConfig, iteration: int) -> float:
    """Geometric annealing from ``temperature_start`` to ``temperature_end`` (``anneal``)."""
    return anneal(config.temperature_start, config.temperature_end, iteration, config.iters)


def training_poses(seed: int, iteration: int, n: int) -> jax.Array:
    """The batch of iteration ``iteration``: a pure function of ``(seed, iteration)``, resumable."""
    seed = check_int("seed", seed, 0, 2**32 - 1)
    iteration = check_int("iteration", iteration, 0, 2**31 - 1)
    stream = jax.random.fold_in(jax.random.key(seed), 0)
    return sample_poses(jax.random.fold_in(stream, iteration), n)


# ---------------------------------------------------------------- state


def checked_config(config: Any) -> TuneConfig:
    """``config`` validated (``None``: ``TuneConfig()``), or say why it is not one."""
    if config is not None and not isinstance(config, TuneConfig):
        raise ValueError(
            f"config = {config!r:.80} is not allowed; allowed: a wmr_jax.tuning.TuneConfig or None"
        )
    return (TuneConfig() if config is None else config).validate()


def _checked(config: TuneConfig | None, robot: Robot | None) -> tuple[TuneConfig, Robot]:
    return checked_config(config), as_float_tree(validate_one_robot(robot, "tuning"))


def _run_text(config: TuneConfig, robot: Robot) -> str:
    """``run_identity`` of checked settings as canonical JSON text (``TrainState.run``).

    Every robot field is part of it, and ``code``, the code that computes
    (``provenance.code_version``): another one is another run.
    """
    robot_values = {f.name: float(getattr(robot, f.name)) for f in dataclasses.fields(Robot)}
    identity = {"config": config.as_dict(), "robot": robot_values, "code": code_version()}
    return json.dumps(identity, sort_keys=True)


def init_state(config: TuneConfig | None = None, robot: Robot | None = None) -> TrainState:
    """Return the state before the first iteration: the paper's feasible gains, Adam at rest.

    For a schedule, the paper's feasible gains as constant tables.

    Raises:
        ValueError: for bad settings, naming the field.
    """
    config, robot = _checked(config, robot)
    problem = config.problem
    z0 = jnp.asarray(problem.start_logits(robot), float_dtype())
    opt_state = _optimizer(config.hyper()).init(z0)
    start = problem.row(problem.from_logits(z0, robot))
    return TrainState(0, z0, opt_state, (), (), (), 0.0, _run_text(config, robot), (), start)


def run_identity(config: TuneConfig | None = None, robot: Robot | None = None) -> dict[str, Any]:
    """What a saved state must match to be resumed: the settings and the robot (JSON-ready)."""
    return json.loads(_run_text(*_checked(config, robot)))


def differences(saved: dict[str, Any], now: dict[str, Any]) -> str:
    """Name what differs between two ``run_identity``s: settings, the robot, the code."""
    there, here = saved.get("config", {}), now["config"]
    if not isinstance(there, dict):
        there = {}
    diffs = [
        f"{key} = {there.get(key)!r} there, {here.get(key)!r} now"
        for key in dict.fromkeys([*here, *there])
        if there.get(key) != here.get(key)
    ]
    if saved.get("robot") != now.get("robot"):
        diffs.append("the robot differs")
    if saved.get("code") != now.get("code"):
        diffs.append(f"computed by wmr_jax {saved.get('code')}, this is {now.get('code')}")
    return "; ".join(diffs) or "the format differs"


def state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    """Return ``state`` as named NumPy arrays, exactly (for a checkpoint file)."""
    leaves = jax.tree.leaves(state.opt_state)
    return {
        "iteration": np.asarray(state.iteration),
        "z": np.asarray(state.z),
        "losses": np.asarray(state.losses, dtype=float),
        "temperatures": np.asarray(state.temperatures, dtype=float),
        "gains": np.asarray(state.gains, dtype=float) if state.gains else np.zeros((0, 0)),
        "elapsed_s": np.asarray(state.elapsed_s, dtype=float),
        "validated": np.asarray(state.validated, dtype=float).reshape(-1, 2),
        "start": np.asarray(state.start, dtype=float),
        **{f"opt_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)},
    }


def restore_state(arrays: dict[str, np.ndarray], fresh: TrainState) -> TrainState:
    """Rebuild the state of ``state_arrays`` in the structure of ``fresh`` (``init_state``).

    A saved state is never trusted: one whose values are not all finite, whose
    iteration count, history lengths and optimiser step counts disagree,
    whose temperatures or elapsed time are not positive, or whose parameter
    rows are not those of ``fresh``'s problem, is refused.

    Raises:
        ValueError: one line, if an array is missing, of the wrong shape,
            non-finite, out of range, or the lengths disagree.
    """
    leaves, treedef = jax.tree.flatten(fresh.opt_state)
    try:
        restored = [
            jnp.asarray(arrays[f"opt_{i}"], dtype=jnp.asarray(leaf).dtype).reshape(jnp.shape(leaf))
            for i, leaf in enumerate(leaves)
        ]
        gains = np.asarray(arrays["gains"], dtype=float)
        iteration = np.asarray(arrays["iteration"])
        if iteration.shape != () or iteration.dtype.kind not in "iu":
            raise ValueError(f"iteration = {iteration!r} is not a whole number")
        state = TrainState(
            iteration=int(iteration),
            z=jnp.asarray(arrays["z"], dtype=fresh.z.dtype).reshape(fresh.z.shape),
            opt_state=jax.tree.unflatten(treedef, restored),
            losses=tuple(float(x) for x in arrays["losses"]),
            temperatures=tuple(float(x) for x in arrays["temperatures"]),
            gains=tuple(tuple(float(x) for x in row) for row in gains.reshape(-1, gains.shape[-1]))
            if gains.size
            else (),
            elapsed_s=float(arrays["elapsed_s"]),
            run=fresh.run,
            validated=tuple(
                (int(i), float(v)) for i, v in np.asarray(arrays["validated"], float).reshape(-1, 2)
            ),
            start=tuple(float(x) for x in np.asarray(arrays["start"], float).reshape(-1)),
        )
    except (KeyError, TypeError, ValueError, IndexError) as err:
        # IndexError: an array of no axes where rows were saved.
        raise ValueError(f"the saved state is incomplete ({type(err).__name__}: {err})") from None
    lengths = {len(state.losses), len(state.temperatures), len(state.gains)}
    if lengths != {state.iteration}:
        raise ValueError(
            f"the saved state is inconsistent: iteration {state.iteration} with histories of "
            f"{len(state.losses)}, {len(state.temperatures)} and {len(state.gains)} rows"
        )
    temperatures = np.asarray(state.temperatures, dtype=float)
    validated = np.asarray(state.validated, dtype=float).reshape(-1, 2)
    values = [state.z, *restored, np.asarray(state.losses), gains, temperatures, validated]
    values.append(np.asarray(state.start, dtype=float))
    if not all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in values):
        raise ValueError("the saved state holds non-finite values (NaN or inf)")
    if not (np.all(temperatures > 0) and np.isfinite(state.elapsed_s) and state.elapsed_s >= 0):
        raise ValueError(
            "the saved state is inconsistent: its temperatures must be > 0 and its elapsed "
            f"time finite and >= 0 (elapsed_s = {state.elapsed_s!r})"
        )
    # Every step count of the optimiser (Adam's, the schedule's) is the iteration.
    counts = [int(leaf) for leaf in restored if leaf.ndim == 0 and leaf.dtype.kind in "iu"]
    if any(count != state.iteration for count in counts):
        raise ValueError(
            f"the saved state is inconsistent: iteration {state.iteration} with optimiser "
            f"step counts {counts}"
        )
    at = [i for i, _ in state.validated]
    if at != sorted(set(at)) or any(not 0 <= i <= state.iteration for i in at):
        raise ValueError(
            f"the saved state is inconsistent: validation scores at iterations {at} "
            f"after {state.iteration}"
        )
    if state.start != fresh.start:
        raise ValueError("the saved state is inconsistent: its start is not this run's")
    # The fixed problem has 7 logits, a schedule of K knots 3K + 5.
    dim = fresh.z.shape[-1]
    problem = FIXED if dim == FIXED.dim else schedule_problem((dim - 5) // 3)
    if state.gains and gains.shape[-1] != len(problem.columns):
        raise ValueError(
            f"the saved state is inconsistent: rows of {gains.shape[-1]} parameters; "
            f"allowed: {len(problem.columns)}, the {problem.name!r} problem's columns"
        )
    return state


# ---------------------------------------------------------------- the loop


def validation_poses(config: TuneConfig) -> jax.Array:
    """The poses the iterates are scored on: from ``config.seed``, apart from every other set.

    Stream 4 of the seed: the training batches are stream 0, the random
    search's candidates and poses 2 and 3; the held-out poses come from
    ``eval_seed``.
    """
    key = jax.random.fold_in(jax.random.key(config.seed), 4)
    return sample_poses(key, config.validation_poses)


def validation_score(config: TuneConfig, robot: Robot, params: Any, refs: Any) -> float:
    """Hard-law score of ``params`` on ``refs``: mean arrival, failures at twice the horizon, s."""
    run = {name: getattr(config, name) for name in RUN_OPTIONS if name != "robot"}
    with warnings.catch_warnings():
        # An iterate is scored, not reported: its warnings (wheel saturation,
        # sampling margins) are the tuner's business; its score says it.
        warnings.simplefilter("ignore")
        _, times, steps = hard_runs(
            refs, params, robot=robot, **run, controller=config.problem.controller
        )
    times = np.asarray(times, dtype=float)
    return float(np.mean(np.minimum(times, FAILURE_FACTOR * steps * config.dt)))


# How much lower an earlier iterate must score than the last to replace it:
# the validation poses are a sample, and the last iterate, annealed to the
# coldest temperature, is what the method aims at. On the paper robot the
# iterates of the last hundred iterations score within 0.2 % of each other;
# where the smooth loss climbs (a slow, wide robot) the last scores 2-3x the best.
BEST_MARGIN = 0.01


def best_iteration(validated: Any, margin: float = BEST_MARGIN) -> int:
    """The iterate to keep, from ``(iteration, score)`` pairs in order (the last one last).

    The last iterate, unless an earlier one scores lower by more than
    ``margin`` (relative); then the lowest score, the later of equal ones.
    """
    validated = [(int(i), float(v)) for i, v in validated]
    last, last_score = validated[-1]
    lowest = min(score for _, score in validated)
    if last_score <= lowest * (1.0 + margin):
        return last
    return max(i for i, score in validated if score == lowest)


def _scored(config, robot, state, refs) -> TrainState:
    """``state`` with its current iterate's validation score appended."""
    problem = config.problem
    row = state.gains[-1] if state.iteration else state.start
    score = validation_score(config, robot, problem.from_row(row), refs)
    return state._replace(validated=state.validated + ((state.iteration, score),))


def _iterate(config, robot, state, progress_fn) -> TrainState:
    """Run the iterations from ``state.iteration`` to ``config.iters``, scoring every few."""
    hyper, dtype = config.hyper(), float_dtype()
    problem = config.problem
    dt = jnp.asarray(config.dt, dtype)
    # The loss runs the loop the evaluation judges: the robot's speed limiter included.
    spec = config.spec().for_robot(robot, dt)
    init = jnp.zeros((3,), dtype)
    refs_val = validation_poses(config)
    if state.iteration == 0 and not state.validated:
        began = time.perf_counter()
        state = _scored(config, robot, state, refs_val)
        state = state._replace(elapsed_s=state.elapsed_s + time.perf_counter() - began)
    for iteration in range(state.iteration, config.iters):
        began = time.perf_counter()
        temperature = _temperature(config, iteration)
        refs = training_poses(config.seed, iteration, config.poses)
        z, opt_state, loss, _ = _train_step_jit(
            state.z,
            state.opt_state,
            refs,
            jnp.asarray(temperature, dtype),
            init,
            robot,
            dt,
            spec=spec,
            hyper=hyper,
            problem=problem,
        )
        loss = float(loss)
        row = problem.row(problem.from_logits(z, robot))
        state = state._replace(
            iteration=iteration + 1,
            z=z,
            opt_state=opt_state,
            losses=state.losses + (loss,),
            temperatures=state.temperatures + (temperature,),
            gains=state.gains + (row,),
        )
        if state.iteration % config.validate_every == 0 or state.iteration == config.iters:
            state = _scored(config, robot, state, refs_val)
        state = state._replace(elapsed_s=state.elapsed_s + time.perf_counter() - began)
        if progress_fn is not None:
            progress_fn(state)
    return state


def _compare(
    config: TuneConfig,
    robot: Robot,
    tuned: Any,
    tune_wall_s: float,
    search_progress: Any,
    eval_progress: Any,
) -> tuple:
    """Random search for the tuning's wall time, then the hard-law table on held-out poses."""
    run = {name: getattr(config, name) for name in RUN_OPTIONS if name != "robot"}
    run["robot"] = robot
    search = None
    if config.random_search:
        stream = jax.random.fold_in(jax.random.key(config.seed), 2)
        refs = sample_poses(jax.random.fold_in(jax.random.key(config.seed), 3), config.poses)
        search = random_search(
            stream,
            refs,
            budget_s=tune_wall_s,
            problem=config.problem,
            progress=search_progress,
            **run,
        )
    held_out = held_out_poses(config.eval_poses, config.eval_seed)
    # The paper's gains scaled into this robot's wheel budget: the baseline
    # must be gains the robot can follow, as the tuned ones are.
    candidates = {"paper_feasible": paper_feasible_gains(robot), "tuned": tuned}
    if search is not None:
        candidates["random_search"] = search.gains
    evaluation = {}
    for name, params in candidates.items():
        evaluation[name] = evaluate(params, held_out, **run)
        if eval_progress is not None:
            eval_progress(name)
    return evaluation, search


def _own_state(state: Any, config: TuneConfig, robot: Robot) -> TrainState:
    """``state`` if it can continue the run of ``config`` and ``robot``, else say why not."""
    if not isinstance(state, TrainState):
        raise ValueError(
            f"state = {state!r:.80} is not allowed; allowed: a TrainState (init_state, or "
            "one handed to progress_fn)"
        )
    dim = config.problem.dim
    if np.shape(state.z) != (dim,):
        raise ValueError(
            f"state holds {np.shape(state.z)} logits; allowed: ({dim},), those of the "
            f"{config.problem.name!r} problem of config"
        )
    if not state.start:  # built by hand: the start is this run's
        problem = config.problem
        start = problem.row(problem.from_logits(problem.start_logits(robot), robot))
        state = state._replace(start=start)
    now = _run_text(config, robot)
    if state.run and state.run != now:
        raise ValueError(
            f"state is of another run ({differences(json.loads(state.run), json.loads(now))}); "
            "allowed: a state of this config and robot"
        )
    return state


def train(
    config: TuneConfig | None = None,
    *,
    robot: Robot | None = None,
    state: TrainState | None = None,
    progress_fn: Callable[[TrainState], Any] | None = None,
    search_progress: Callable[[int], Any] | None = None,
    eval_progress: Callable[[str], Any] | None = None,
) -> TuneResult:
    """Tune the gains by gradient descent, then judge them with the hard law.

    Writes no files and draws nothing: ``progress_fn(state)`` is called after
    each iteration (an exception it raises stops the run), and the returned
    result holds the gains, the history and the before/after evaluation.

    Args:
        config: the settings; default ``TuneConfig()``.
        robot: robot parameters; default ``Robot()``.
        state: continue from this state (from ``init_state`` or a
            ``progress_fn`` call of a run with the same ``config`` and
            ``robot``); the result is that of an uninterrupted run.
        progress_fn: called with the ``TrainState`` after each iteration.
        search_progress: called with the number of candidates the random
            search scored, after each chunk of them.
        eval_progress: called with the row's name after each hard-law evaluation.

    Returns:
        A ``TuneResult``.

    Raises:
        ValueError: for bad settings, naming the field.
    """
    config, robot = _checked(config, robot)
    for name, fn in (
        ("progress_fn", progress_fn),
        ("search_progress", search_progress),
        ("eval_progress", eval_progress),
    ):
        check_callable(name, fn)
    state = init_state(config, robot) if state is None else _own_state(state, config, robot)
    if not 0 <= state.iteration <= config.iters:
        raise ValueError(
            f"state.iteration = {state.iteration!r} is not allowed; "
            f"allowed: 0 to iters = {config.iters}"
        )
    state = _iterate(config, robot, state, progress_fn)
    if not state.gains:
        raise ValueError("state holds no iteration; allowed: a state after at least one")
    problem = config.problem
    if not state.validated or state.validated[-1][0] != state.iteration:
        # A state handed in after its last iteration, not scored there yet.
        state = _scored(config, robot, state, validation_poses(config))
    best = best_iteration(state.validated)
    tuned = problem.from_row(state.gains[best - 1] if best else state.start)
    history = {
        "loss": np.asarray(state.losses),
        "temperature": np.asarray(state.temperatures),
        "gains": np.asarray(state.gains).reshape(len(state.gains), -1),
        "validated_at": np.asarray([i for i, _ in state.validated], dtype=int),
        "validation": np.asarray([v for _, v in state.validated], dtype=float),
    }
    evaluation, search = _compare(
        config, robot, tuned, state.elapsed_s, search_progress, eval_progress
    )
    note = baseline_note(evaluation, "paper_feasible", "tuned")
    return TuneResult(tuned, evaluation, history, state.elapsed_s, search, problem.name, best, note)


def baseline_note(evaluation: dict[str, Any], baseline: str, tuned: str) -> str | None:
    """One line when the ``tuned`` row is no better than the ``baseline`` row, else ``None``.

    No better: it arrives less often, or as often and no sooner on average
    (hard law, held-out poses).
    """
    ours, theirs = evaluation[tuned], evaluation[baseline]
    if ours.success_rate > theirs.success_rate or (
        ours.success_rate == theirs.success_rate and ours.mean_arrival < theirs.mean_arrival
    ):
        return None
    return (
        f"warning: the tuned parameters are no better than the baseline ({baseline}): "
        f"{ours.mean_arrival:.3f} s at {ours.success_rate:.0%} success against "
        f"{theirs.mean_arrival:.3f} s at {theirs.success_rate:.0%} on the held-out poses"
    )
