"""The fixed-gain and gain-schedule problems of the trainer, and ``train``."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    as_float_tree,
    check_bool,
    check_callable,
    check_int,
    check_number,
    float_dtype,
)
from wmr_jax._src.model.controllers.schedule import KNOTS
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.poses import HORIZON_S, MAX_SAMPLES, sample_poses
from wmr_jax._src.tuning import trainer
from wmr_jax._src.tuning.evaluation import (
    EVAL_POSES,
    EVAL_SEED,
    RUN_OPTIONS,
    evaluate,
    hard_runs,
    held_out_poses,
    quiet_scoring,
    run_horizon,
)
from wmr_jax._src.tuning.loss import LossSpec, LossWeights, make_spec, robust_value_and_grad
from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
from wmr_jax._src.tuning.problems import FIXED, MAX_TUNED_KNOTS, Problem, schedule_problem
from wmr_jax._src.tuning.search import FAILURE_FACTOR, random_search
from wmr_jax._src.tuning.trainer import TrainState, TuneResult

# The gain schedule's settings where they differ from the fixed gains': its
# parameters need more and longer steps than seven, and a colder end of the
# annealing helps it (not the fixed gains); docs/tuning.md.
SCHEDULE_SETTINGS = {"iters": 600, "learning_rate": 0.2, "temperature_end": 0.003}


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Everything that decides the result of ``train`` (saved with each checkpoint).

    Attributes:
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (``docs/model.md §4``).
        iters: Adam iterations.
        poses: reference poses per iteration, a fresh batch each time.
        seed: seed of the training poses and of the random search.
        learning_rate: Adam's initial step in logit space (cosine-decayed).
        grad_clip: ``clip_by_global_norm`` threshold of the batch gradient.
        pose_clip: cap of each pose's gradient norm, in multiples of the
            batch median; ``None`` for a plain mean.
        temperature_start: smooth-law temperature of the first iteration.
        temperature_end: temperature of the last (annealed geometrically).
        horizon: simulated time per run, s; ``None``: the robot's study
            horizon (``studies.study_horizon``).
        dt: control period, s.
        checkpoint_every: iterations between checkpoints (of ``wmr-jax tune``).
        eval_poses: held-out poses of the before/after table.
        eval_seed: seed of the held-out poses (the same for every ``seed``).
        random_search: also run random search for the tuning's CPU time.
        weights: terms of the loss (see ``tuning_loss``).
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        problem: ``"fixed"`` (the seven gains) or ``"schedule"`` (the
            gain-scheduled law, ``ScheduleParams``, ``3 knots + 5`` parameters).
        knots: knots per table of the schedule (schedules only).
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
    horizon: float | None = None
    dt: float = simulation.DEFAULT_DT
    checkpoint_every: int = trainer.CHECKPOINT_EVERY
    eval_poses: int = EVAL_POSES
    eval_seed: int = EVAL_SEED
    random_search: bool = True
    weights: LossWeights = LossWeights()
    substeps: int = loops.DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"
    problem: str = "fixed"
    knots: int = KNOTS
    validate_every: int = 25
    validation_poses: int = 128

    @classmethod
    def for_problem(cls, problem: str = "fixed", **changes: Any) -> TuneConfig:
        """The recommended settings of ``problem``, with ``changes`` on top.

        ``"fixed"`` is ``TuneConfig()``; ``"schedule"`` also sets
        ``SCHEDULE_SETTINGS``. ``ValueError`` for another ``problem``.
        """
        problem = getattr(problem, "name", problem)  # a Problem, or its name
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"{unknown[0]!r} is not allowed; allowed: the fields of TuneConfig")
        if problem == "fixed":
            return cls(**changes)
        if problem == "schedule":
            return cls(**{"problem": "schedule", **SCHEDULE_SETTINGS, **changes})
        raise ValueError(f"problem = {problem!r} is not allowed; allowed: 'fixed', 'schedule'")

    @property
    def space(self) -> Problem:
        """The searched set: gain schedules of ``knots`` knots, or the fixed gains."""
        return schedule_problem(self.knots) if self.problem == "schedule" else FIXED

    @property
    def hard_run(self) -> dict[str, Any]:
        """The options of a hard-law run of these settings (``RUN_OPTIONS`` but the robot)."""
        return {name: getattr(self, name) for name in RUN_OPTIONS if name != "robot"}

    def replace(self, **changes: Any) -> TuneConfig:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)

    def for_robot(self, robot: Robot) -> TuneConfig:
        """These settings with a ``horizon`` of ``None`` set to ``robot``'s study horizon."""
        if self.horizon is not None:
            return self
        return self.replace(horizon=run_horizon(None, robot)).validate()

    def validate(self) -> TuneConfig:
        """Check every field; return ``self`` (``ValueError`` naming the field)."""
        trainer.check_loop(self)
        for name, minimum, maximum in _INT_FIELDS:
            check_int(name, getattr(self, name), minimum, maximum)
        check_number("grad_clip", self.grad_clip)
        if self.pose_clip is not None:
            check_number("pose_clip", self.pose_clip)
        check_bool("random_search", self.random_search)
        if self.problem not in ("fixed", "schedule"):
            raise ValueError(
                f"problem = {self.problem!r} is not allowed; allowed: 'fixed', 'schedule' "
                "('robust': RobustConfig)"
            )
        if self.problem == "fixed" and self.knots != KNOTS:
            raise ValueError(
                f"knots = {self.knots!r} is not allowed with problem = 'fixed'; allowed: knots "
                "for a gain schedule only (TuneConfig.for_problem('schedule', knots=...))"
            )
        self.spec()
        return self

    def spec(self) -> LossSpec:
        """The static loss settings of this configuration (checked); a ``horizon`` of
        ``None`` is the paper robot's here (``for_robot`` sets another robot's)."""
        return make_spec(
            horizon=HORIZON_S if self.horizon is None else self.horizon,
            dt=self.dt,
            velocity=self.velocity,
            substeps=self.substeps,
            wheel_limit=self.wheel_limit,
            weights=self.weights,
            controller=self.space.controller,
        )

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as JSON-ready values."""
        return dataclasses.asdict(self)


# name, minimum, maximum of the integer fields of TuneConfig beyond the loop's.
_INT_FIELDS = (
    ("checkpoint_every", 1, None),
    ("eval_seed", 0, 2**32 - 1),
    ("knots", 2, MAX_TUNED_KNOTS),
)


@dataclasses.dataclass(frozen=True)
class GainLoss:
    """The fixed-gain or schedule loss of one iteration (``robust_value_and_grad``), hashable."""

    spec: LossSpec
    problem: Problem
    pose_clip: float | None

    def __call__(self, z, refs, temperature, consts):
        init, robot, dt = consts
        return robust_value_and_grad(
            z, refs, init, robot, dt, self.spec, temperature, self.pose_clip, self.problem
        )[:2]


def gain_problem(config: TuneConfig, robot: Robot) -> trainer.TrainingProblem:
    """The ``TrainingProblem`` of a checked ``config`` on a checked ``robot``."""
    config = config.for_robot(robot)
    space, dtype = config.space, float_dtype()
    dt = jnp.asarray(config.dt, dtype)
    # The loss runs the loop the evaluation judges: the robot's speed limiter included.
    spec = config.spec().for_robot(robot, dt)
    pose_clip = None if config.pose_clip is None else float(config.pose_clip)
    # Stream 4 of the seed, apart from the training's 0 and the random search's 2 and 3.
    refs = sample_poses(jax.random.fold_in(jax.random.key(config.seed), 4), config.validation_poses)
    return trainer.TrainingProblem(
        name=space.name,
        z0=jnp.asarray(space.start_logits(robot), dtype),
        loss=GainLoss(spec, space, pose_clip),
        consts=(jnp.zeros((3,), dtype), robot, dt),
        batch=lambda iteration: training_poses(config.seed, iteration, config.poses),
        row=lambda z: space.row(space.from_logits(z, robot)),
        from_row=space.from_row,
        score=lambda params: validation_score(config, robot, params, refs),
        hyper=trainer.Hyper(
            float(config.learning_rate), int(config.iters), float(config.grad_clip)
        ),
        temperature_start=config.temperature_start,
        temperature_end=config.temperature_end,
        validate_every=config.validate_every,
    )


def training_poses(seed: int, iteration: int, n: int) -> jax.Array:
    """The batch of iteration ``iteration``: a pure function of ``(seed, iteration)``, resumable."""
    seed = check_int("seed", seed, 0, 2**32 - 1)
    iteration = check_int("iteration", iteration, 0, 2**31 - 1)
    check_int("n", n, 0, MAX_SAMPLES)  # before the key
    stream = jax.random.fold_in(jax.random.key(seed), 0)
    return sample_poses(jax.random.fold_in(stream, iteration), n)


def _checked(config: TuneConfig | None, robot: Robot | None) -> tuple[TuneConfig, Robot]:
    """The checked settings over the robot's horizon (unless given), and the robot."""
    config = trainer.checked_config(config, TuneConfig)
    robot = validate_one_robot(robot, "tuning")
    return config.for_robot(robot), as_float_tree(robot)


def init_state(config: TuneConfig | None = None, robot: Robot | None = None) -> TrainState:
    """Return the state before the first iteration: the paper's feasible gains (a
    schedule: as constant tables), Adam at rest. ``ValueError`` names a bad field."""
    config, robot = _checked(config, robot)
    return trainer.start_state(gain_problem(config, robot), trainer.run_text(config, robot))


def run_identity(config: TuneConfig | None = None, robot: Robot | None = None) -> dict[str, Any]:
    """What a saved state must match to be resumed: the settings and the robot (JSON-ready)."""
    return json.loads(trainer.run_text(*_checked(config, robot)))


def validation_score(config: TuneConfig, robot: Robot, params: Any, refs: Any) -> float:
    """Hard-law score of ``params`` on ``refs``: mean arrival, failures at twice the horizon, s."""
    with quiet_scoring():
        _, times, steps = hard_runs(
            refs, params, robot=robot, **config.hard_run, controller=config.space.controller
        )
    times = np.asarray(times, dtype=float)
    return float(np.mean(np.minimum(times, FAILURE_FACTOR * steps * config.dt)))


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

    The robust batch gradient of ``tuning_loss``, from the paper's feasible gains;
    then the paper's, the tuned and a random search's gains (same CPU time) are
    judged on held-out poses. Writes no files and draws nothing.

    Args:
        config: the settings; default ``TuneConfig()``.
        robot: robot parameters; default ``Robot()``.
        state: continue from this state (from ``init_state`` or a
            ``progress_fn`` call of a run with the same ``config`` and
            ``robot``); the result is that of an uninterrupted run.
        progress_fn: called with the ``TrainState`` after each iteration (an
            exception it raises stops the run).
        search_progress: called with the number of candidates the random
            search scored, after each chunk of them.
        eval_progress: called with the row's name after each hard-law evaluation.

    Returns:
        A ``TuneResult``.

    Raises:
        ValueError: for bad settings, naming the field.
    """
    config, robot = _checked(config, robot)
    check_callable("progress_fn", progress_fn)
    trainer.check_state(state)
    check_callable("search_progress", search_progress)
    check_callable("eval_progress", eval_progress)
    problem, identity = gain_problem(config, robot), trainer.run_text(config, robot)
    tuned, best, history, state = trainer.fit(problem, identity, state, progress_fn)
    run = {**config.hard_run, "robot": robot}
    search = None
    if config.random_search:
        stream = jax.random.fold_in(jax.random.key(config.seed), 2)
        refs = sample_poses(jax.random.fold_in(jax.random.key(config.seed), 3), config.poses)
        search = random_search(
            stream,
            refs,
            budget_s=state.elapsed_s,
            problem=config.space,
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
    note = baseline_note(evaluation, "paper_feasible", "tuned")
    return TuneResult(tuned, evaluation, history, state.elapsed_s, search, problem.name, best, note)


def baseline_note(evaluation: dict[str, Any], baseline: str, tuned: str) -> str | None:
    """A line when ``tuned`` arrives less often than ``baseline``, or as often and no sooner."""
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
