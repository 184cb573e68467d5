"""Bad arguments are refused by name before the entry point does any JAX work.

Each case replaces the first JAX step the entry point would take (a key made
or split, a draw, a logistic) with one that fails the test: the refusal must
come first, as one ``ValueError`` naming the argument.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import studies, tuning
from wmr_jax._src.sim.sensing import disturbances
from wmr_jax._src.studies import maps
from wmr_jax._src.tuning import robust, training

REFS = np.array([[30.0, 0.0, 0.0], [0.0, 30.0, 1.0]])
HUGE = 2**62


def _no_work(*args, **kwargs):
    raise AssertionError("JAX work began before the arguments were checked")


@pytest.fixture
def no_keys(monkeypatch):
    """No key is made, split or folded, and no sigmoid or exponential runs."""
    for name in ("key", "PRNGKey", "split", "fold_in"):
        monkeypatch.setattr(jax.random, name, _no_work)
    monkeypatch.setattr(jax.nn, "sigmoid", _no_work)
    monkeypatch.setattr(jnp, "exp", _no_work)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: w.sample_poses(3, -1), "n = -1 is not allowed"),
        (lambda: w.sample_poses(3, 4, dtype="int8"), "dtype = 'int8' is not allowed"),
        (lambda: tuning.held_out_poses(-1), "n = -1 is not allowed"),
        (lambda: tuning.training_poses(0, 0, HUGE), f"n = {HUGE} is not allowed"),
        (
            lambda: tuning.gains_from_logits(np.zeros(7), robot="x"),
            "robot = 'x' is not allowed; allowed: a Robot (wmr_jax.load_robot",
        ),
        (
            lambda: tuning.robust_gains(np.zeros(7), robot="x"),
            "robot = 'x' is not allowed; allowed: a Robot (wmr_jax.load_robot",
        ),
        (lambda: training.train(tuning.TuneConfig(iters=2), state="x"), "state = 'x'"),
        (lambda: robust.tune_robust(tuning.RobustConfig(iters=2), state="x"), "state = 'x'"),
    ],
)
def test_refused_before_any_key_or_logistic(no_keys, call, message):
    with pytest.raises(ValueError, match="allowed") as info:
        call()
    assert message in str(info.value)


def test_draws_refuse_their_counts_by_name_within_int32(monkeypatch):
    monkeypatch.setattr(jax.random, "split", _no_work)
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=f"n = {HUGE} is not allowed; allowed: an integer >= 1"):
        disturbances.draw_disturbances(key, HUGE, 10)
    with pytest.raises(ValueError, match=f"steps = {HUGE} is not allowed"):
        disturbances.draw_disturbances(key, 4, HUGE)
    with pytest.raises(ValueError, match=f"steps = {HUGE} is not allowed"):
        studies.sample_disturbance(key, REFS, HUGE)
    with pytest.raises(ValueError, match="noise_xy = -1.0 is not allowed"):
        studies.sample_disturbance(key, REFS, 10, noise_xy=-1.0)


@pytest.mark.parametrize(
    ("search", "kwargs", "name"),
    [
        (tuning.random_search, {"chunk": HUGE}, "chunk"),
        (tuning.cma_es_search, {"population": HUGE}, "population"),
    ],
)
def test_searches_refuse_a_batch_beyond_the_samples_by_name(search, kwargs, name):
    with pytest.raises(ValueError, match=f"{name} = {HUGE} is not allowed; allowed: an integer"):
        search(jax.random.key(0), REFS, budget_s=1.0, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"velocity": "foo"}, "velocity = 'foo' is not allowed"),
        ({"chunk": 0}, "chunk = 0 is not allowed"),
        ({"x64": "yes"}, "x64 = 'yes' is not allowed"),
        ({"progress": "no"}, "progress = 'no' is not allowed"),
    ],
)
def test_compare_controllers_refuses_its_run_options_before_drawing_poses(
    monkeypatch, kwargs, message
):
    monkeypatch.setattr(maps, "sample_poses", _no_work)
    with pytest.raises(ValueError, match="allowed") as info:
        studies.compare_controllers(n_poses=4, **kwargs)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"z": np.zeros(3)}, r"z has shape (3,); allowed: (7,) for 'fixed'"),
        ({"z": np.zeros(7), "pose_clip": -1.0}, "pose_clip = -1.0 is not allowed"),
    ],
)
def test_robust_gradient_refuses_its_logits_and_cap_by_name(kwargs, message):
    with pytest.raises(ValueError, match="allowed") as info:
        tuning.robust_gradient(refs=REFS, temperature=0.1, **kwargs)
    assert message in str(info.value)
