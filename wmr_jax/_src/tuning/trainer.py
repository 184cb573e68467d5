"""The one gradient trainer: optax on a problem's logits, annealed, best iterate by validation.

A ``TrainingProblem`` holds what differs between the tuning problems;
``fit`` runs the one loop for any of them. A run continues bit for bit from
any ``TrainState`` that ``progress_fn`` saw.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from wmr_jax._src.checks import check_int, check_number, float_dtype
from wmr_jax._src.model.params import Robot
from wmr_jax._src.provenance import code_version
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.poses import MAX_SAMPLES
from wmr_jax._src.sim.rollout import check_temperature
from wmr_jax._src.tuning.search import clock


@dataclasses.dataclass(frozen=True)
class Hyper:
    """Static optimiser settings (part of the train step's compile key)."""

    learning_rate: float
    iters: int
    grad_clip: float = 1.0


class TrainingProblem(NamedTuple):
    """A tuning problem as the trainer runs it.

    Attributes:
        name: ``"fixed"``, ``"schedule"`` or ``"robust"``.
        z0: ``(dim,)`` logits of the start.
        loss: ``loss(z, batch, temperature, consts) -> (loss s, gradient (dim,))``,
            traceable and hashable (static in the compiled step).
        consts: traced arguments of ``loss`` shared by every iteration (robot, dt).
        batch: ``batch(iteration)``, the iteration's draw (a pure function of it).
        row: ``row(z)``, the parameters of ``z`` as a flat tuple of floats.
        from_row: ``from_row(row)``, the parameters a result holds.
        score: ``score(params)``, the hard-law validation score, s.
        hyper: the optimiser settings.
        temperature_start, temperature_end: smooth-law temperatures of the
            first and the last iteration.
        validate_every: iterations between validation scores.
    """

    name: str
    z0: jax.Array
    loss: Any
    consts: Any
    batch: Callable[[int], Any]
    row: Callable[[Any], tuple[float, ...]]
    from_row: Callable[[Any], Any]
    score: Callable[[Any], float]
    hyper: Hyper
    temperature_start: float
    temperature_end: float
    validate_every: int


class TrainState(NamedTuple):
    """The whole state of a tuning run after ``iteration`` iterations.

    Attributes:
        iteration: iterations done.
        z: ``(dim,)`` logits of the current parameters.
        opt_state: the optax state.
        losses, temperatures: of each iteration done (s; the smooth law's).
        gains: the parameters after each iteration as rows (``TrainingProblem.row``).
        elapsed_s: process CPU time (``search.clock``) of the iterations done, all sessions, s.
        run: the run's identity (``run_text``); a state of another run is
            refused. Empty (a state built by hand): not checked.
        validated: ``(iteration, score s)`` of each validation score so far, in order.
        start: the start's parameters as a row.
        lowest_z: the logits of the iterate of the lowest validation score so
            far (the later of equal ones), ``None`` before the first: with
            ``z`` they are every iterate ``best_iteration`` can keep.
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
    lowest_z: Any = None


class TuneResult(NamedTuple):
    """What a tuning run returns, whatever its problem.

    Attributes:
        gains: the tuned parameters (floats): ``Gains`` or ``ScheduleParams``.
        evaluation: hard-law ``Evaluation`` on the held-out poses, keyed
            ``"paper_feasible"``, ``"tuned"`` and ``"random_search"`` if run
            (empty for the robust problem, judged by ``rows``).
        history: per-iteration ``loss`` (s), ``temperature`` and ``gains``
            rows, and the validation scores ``validated_at`` (iterations) and
            ``validation`` (s), as NumPy arrays.
        tune_cpu_s: process CPU time of the gradient iterations (all sessions), s.
        search: the random search's ``SearchResult``, or ``None``.
        problem: ``"fixed"``, ``"schedule"`` or ``"robust"``.
        best_iteration: the iterate returned (0: the start), by ``best_iteration``.
        note: one line when the result is no better than the baseline, else ``None``.
        loop: the robust problem's tuned ``ClosedLoop``, else ``None``.
        rows: the robust problem's ``standard_conditions`` rows of the paper's
            gains, the tuned loop and the searches' loops, else ``None``.
        searches: the robust problem's ``{method: (ClosedLoop, candidates, CPU s,
            wall s)}``, else ``None``.
        budget: the robust comparison's ``{"price", "measured_price",
            "candidates"}`` (``robust_run.compare_seed``), else ``None``.
    """

    gains: Any
    evaluation: dict[str, Any]
    history: dict[str, np.ndarray]
    tune_cpu_s: float
    search: Any
    problem: str = "fixed"
    best_iteration: int = 0
    note: str | None = None
    loop: Any = None
    rows: list[dict[str, Any]] | None = None
    searches: dict[str, Any] | None = None
    budget: dict[str, float] | None = None


# name, minimum, maximum of the integer fields every tuning config has.
_LOOP_INTS = (
    ("iters", 1, None),
    ("poses", 1, MAX_SAMPLES),
    ("seed", 0, 2**32 - 1),
    ("eval_poses", 1, MAX_SAMPLES),
    ("validate_every", 1, None),
    ("validation_poses", 1, MAX_SAMPLES),
)


def check_loop(config: Any) -> None:
    """Check the loop fields every tuning config shares (``ValueError`` naming the field)."""
    for name, minimum, maximum in _LOOP_INTS:
        check_int(name, getattr(config, name), minimum, maximum)
    check_number("learning_rate", config.learning_rate)
    for name in ("temperature_start", "temperature_end"):
        check_temperature(name, getattr(config, name))
    if config.temperature_end > config.temperature_start:  # annealing sharpens the law
        raise ValueError(
            f"temperature_end = {config.temperature_end!r} is not allowed; allowed: at most "
            f"temperature_start ({config.temperature_start!r}): the law is annealed towards the "
            "hard one"
        )


def checked_config(config: Any, kind: type) -> Any:
    """``config`` validated (``None``: ``kind()``), or say why it is not a ``kind``."""
    if config is not None and not isinstance(config, kind):
        raise ValueError(
            f"config = {config!r:.80} is not allowed; allowed: a "
            f"wmr_jax.tuning.{kind.__name__} or None"
        )
    return (kind() if config is None else config).validate()


def optimizer(hyper: Hyper) -> optax.GradientTransformation:
    """``clip_by_global_norm`` then Adam, its step cosine-decayed to a tenth: large
    steps while the landscape is smooth, small ones near the hard law."""
    schedule = optax.cosine_decay_schedule(hyper.learning_rate, hyper.iters, alpha=0.1)
    return optax.chain(optax.clip_by_global_norm(hyper.grad_clip), optax.adam(schedule))


def _train_step(z, opt_state, batch, temperature, consts, *, loss, hyper):
    value, grad = loss(z, batch, temperature, consts)
    updates, opt_state = optimizer(hyper).update(grad, opt_state, z)
    # Feasibility needs no projection: every z maps into the feasible set.
    return optax.apply_updates(z, updates), opt_state, value


# One compiled optimiser step of any problem: ``(z, opt_state, loss)``.
train_step = loops.jit_top_level(_train_step, static_argnames=("loss", "hyper"))


# Iterations between checkpoints of the tuning commands, unless told otherwise.
CHECKPOINT_EVERY = 25

# How much lower an earlier iterate must score than the last to replace it:
# the validation poses are a sample, and the last iterate, annealed to the
# coldest temperature, is what the method aims at.
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


def start_state(problem: TrainingProblem, run: str = "") -> TrainState:
    """The state before the first iteration: the problem's start, Adam at rest."""
    opt_state = optimizer(problem.hyper).init(problem.z0)
    start = problem.row(problem.z0)
    return TrainState(0, problem.z0, opt_state, (), (), (), 0.0, run, (), start)


def _scored(problem: TrainingProblem, state: TrainState) -> TrainState:
    """``state`` with its current iterate's validation score appended."""
    row = state.gains[-1] if state.iteration else state.start
    score = problem.score(problem.from_row(row))
    lowest = state.lowest_z
    if lowest is None or score <= min(v for _, v in state.validated):
        lowest = state.z
    return state._replace(validated=state.validated + ((state.iteration, score),), lowest_z=lowest)


def iterate(
    problem: TrainingProblem, state: TrainState, progress_fn: Callable | None = None
) -> TrainState:
    """Run the iterations from ``state.iteration`` to ``hyper.iters``, scoring every few."""
    dtype, iters = float_dtype(), problem.hyper.iters
    start, end = problem.temperature_start, problem.temperature_end
    if state.iteration == 0 and not state.validated:
        began = clock()
        state = _scored(problem, state)
        state = state._replace(elapsed_s=state.elapsed_s + clock() - began)
    for iteration in range(state.iteration, iters):
        began = clock()
        # Geometric: the start's at iteration 0, the end's at the last.
        temperature = start * (end / start) ** (iteration / max(iters - 1, 1))
        z, opt_state, loss = train_step(
            state.z,
            state.opt_state,
            problem.batch(iteration),
            jnp.asarray(temperature, dtype),
            problem.consts,
            loss=problem.loss,
            hyper=problem.hyper,
        )
        state = state._replace(
            iteration=iteration + 1,
            z=z,
            opt_state=opt_state,
            losses=state.losses + (float(loss),),
            temperatures=state.temperatures + (temperature,),
            gains=state.gains + (problem.row(z),),
        )
        if state.iteration % problem.validate_every == 0 or state.iteration == iters:
            state = _scored(problem, state)
        state = state._replace(elapsed_s=state.elapsed_s + clock() - began)
        if progress_fn is not None:
            progress_fn(state)
    return state


def fit(
    problem: TrainingProblem, run: str, state: TrainState | None = None, progress_fn: Any = None
) -> tuple[Any, int, dict[str, np.ndarray], TrainState]:
    """Train ``problem`` from ``state`` (default its start) to its last iteration.

    ``run``: the run's identity (``run_text``), which ``state`` must share.
    Returns ``(parameters kept, their iteration, history, last state)``;
    ``ValueError`` for a state of another run or problem, or of no iteration.
    """
    state = start_state(problem, run) if state is None else own_state(state, problem, run)
    state = iterate(problem, state, progress_fn)
    if not state.gains:
        raise ValueError("state holds no iteration; allowed: a state after at least one")
    if not state.validated or state.validated[-1][0] != state.iteration:
        # A state handed in after its last iteration, not scored there yet.
        state = _scored(problem, state)
    best = best_iteration(state.validated)
    history = {
        "loss": np.asarray(state.losses),
        "temperature": np.asarray(state.temperatures),
        "gains": np.asarray(state.gains).reshape(len(state.gains), -1),
        "validated_at": np.asarray([i for i, _ in state.validated], dtype=int),
        "validation": np.asarray([v for _, v in state.validated], dtype=float),
    }
    return problem.from_row(state.gains[best - 1] if best else state.start), best, history, state


def verdict(result: TuneResult, validation_poses: int) -> dict[str, Any]:
    """The iterate kept, its validation scores and the baseline note, JSON-ready (result files)."""
    return {
        "best_iteration": result.best_iteration,
        "validation": {
            "poses": validation_poses,
            "scored_at": [int(i) for i in result.history["validated_at"]],
            "score_s": [float(v) for v in result.history["validation"]],
        },
        "no_better_than_baseline": result.note is not None,
        "note": result.note,
    }


def identity_config(config: Any) -> dict[str, Any]:
    """The settings that decide a run's result as JSON reads them: all but how often it
    checkpoints. ``config``: a tuning config, or its fields as read from a file."""
    values = config if isinstance(config, dict) else json.loads(json.dumps(config.as_dict()))
    return {k: v for k, v in values.items() if k != "checkpoint_every"}


def run_text(config: Any, robot: Robot) -> str:
    """The identity of a run as canonical JSON text: settings, robot, code version."""
    robot_values = {f.name: float(getattr(robot, f.name)) for f in dataclasses.fields(Robot)}
    identity = {"config": identity_config(config), "robot": robot_values, "code": code_version()}
    return json.dumps(identity, sort_keys=True)


def _command(config: dict[str, Any]) -> str:
    """The command whose settings ``config`` holds (a run identity's, as read)."""
    return "tune --robust" if "law" in config else f"tune ({config.get('problem')})"


def differences(saved: dict[str, Any], now: dict[str, Any]) -> str:
    """Name what differs between two run identities: settings, the robot, the code."""
    there, here = saved.get("config", {}), now["config"]
    if not isinstance(there, dict):
        there = {}
    if there and _command(there) != _command(here):  # another problem: its fields differ too
        return f"a run of {_command(there)} there, {_command(here)} now"
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


def check_state(state: Any, name: str = "state", *, optional: bool = True) -> None:
    """Refuse a ``state`` that is not a ``TrainState`` (nor ``None``, if ``optional``)."""
    if not (isinstance(state, TrainState) or (optional and state is None)):
        raise ValueError(
            f"{name} = {state!r:.80} is not allowed; allowed: a TrainState (init_state, or "
            "one handed to progress_fn)"
        )


def own_state(state: Any, problem: TrainingProblem, run: str) -> TrainState:
    """``state`` if it can continue the run ``run`` of ``problem``, else say why not."""
    check_state(state)
    dim = np.shape(problem.z0)
    if np.shape(state.z) != dim:
        raise ValueError(
            f"state holds {np.shape(state.z)} logits; allowed: {dim}, those of the "
            f"{problem.name!r} problem of config"
        )
    if not state.start:  # built by hand: the start is this run's
        state = state._replace(start=problem.row(problem.z0))
    if state.run and state.run != run:
        raise ValueError(
            f"state is of another run ({differences(json.loads(state.run), json.loads(run))}); "
            "allowed: a state of this config and robot"
        )
    if not 0 <= state.iteration <= problem.hyper.iters:
        raise ValueError(
            f"state.iteration = {state.iteration!r} is not allowed; "
            f"allowed: 0 to iters = {problem.hyper.iters}"
        )
    return state


def state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    """Return ``state`` as named NumPy arrays, exactly (for a checkpoint file)."""
    check_state(state, optional=False)
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
        # Before the first score there is none: z stands in, and is not read back.
        "lowest_z": np.asarray(state.z if state.lowest_z is None else state.lowest_z),
        **{f"opt_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)},
    }


def restore_state(arrays: dict[str, np.ndarray], fresh: TrainState) -> TrainState:
    """Rebuild the state of ``state_arrays`` in the structure of ``fresh`` (``init_state``).

    Never trusted: non-finite values, disagreeing counts or lengths, and rows not
    as long as ``fresh``'s start are refused in one line (``ValueError``).
    """
    check_state(fresh, "fresh", optional=False)
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
        lowest = jnp.asarray(arrays["lowest_z"], dtype=fresh.z.dtype).reshape(fresh.z.shape)
        state = state._replace(lowest_z=lowest if state.validated else None)
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
    values = [state.z, *restored, state.losses, gains, temperatures, state.validated, state.start]
    if state.lowest_z is not None:
        values.append(state.lowest_z)
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
    if state.gains and gains.shape[-1] != len(fresh.start):
        raise ValueError(
            f"the saved state is inconsistent: rows of {gains.shape[-1]} parameters; "
            f"allowed: {len(fresh.start)}, the problem's columns"
        )
    return state
