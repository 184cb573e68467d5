"""Gradient-based gain tuning under ``k_r + L k_θ ≤ V_max``, with optax.

Which feasible gains bring the robot to its reference fastest, over a
distribution of reference poses (``docs/model.md §6`` by default)? Adam
descends a differentiable surrogate of the arrival time through the law's
smooth relaxation, the relaxation is annealed towards the hard law, and the
result is compared, with the hard law, against the paper's feasible gains and
against a plain random search given the same CPU time.

The modules, one concept each, are listed in ``docs/custom_controller.md``:
the feasible sets (``parametrisation``, ``problems``, ``estimation``), the
loss, the one gradient loop (``trainer``) and its problems (``training``:
fixed gains and schedules; ``robust``: the joint robust problem), the
black-box baselines (``search``), their comparison, the hard-law evaluation,
a run's files (``run``, ``robust_run``) and tuned files (``saved``).
"""

from wmr_jax._src.tuning.cost import GradientCost as GradientCost
from wmr_jax._src.tuning.cost import gradient_cost as gradient_cost
from wmr_jax._src.tuning.evaluation import EVAL_POSES as EVAL_POSES
from wmr_jax._src.tuning.evaluation import EVAL_SEED as EVAL_SEED
from wmr_jax._src.tuning.evaluation import Evaluation as Evaluation
from wmr_jax._src.tuning.evaluation import evaluate as evaluate
from wmr_jax._src.tuning.evaluation import held_out_poses as held_out_poses
from wmr_jax._src.tuning.loss import LossTerms as LossTerms
from wmr_jax._src.tuning.loss import LossWeights as LossWeights
from wmr_jax._src.tuning.loss import loss_terms as loss_terms
from wmr_jax._src.tuning.loss import robust_gradient as robust_gradient
from wmr_jax._src.tuning.loss import tuning_loss as tuning_loss
from wmr_jax._src.tuning.parametrisation import GAIN_FIELDS as GAIN_FIELDS
from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS as PAPER_FEASIBLE_GAINS
from wmr_jax._src.tuning.parametrisation import gains_as_dict as gains_as_dict
from wmr_jax._src.tuning.parametrisation import gains_from_logits as gains_from_logits
from wmr_jax._src.tuning.parametrisation import gains_from_unit as gains_from_unit
from wmr_jax._src.tuning.parametrisation import logits_from_gains as logits_from_gains
from wmr_jax._src.tuning.parametrisation import unit_from_gains as unit_from_gains
from wmr_jax._src.tuning.problems import FIXED as FIXED
from wmr_jax._src.tuning.problems import SCHEDULED as SCHEDULED
from wmr_jax._src.tuning.problems import Problem as Problem
from wmr_jax._src.tuning.problems import get_problem as get_problem
from wmr_jax._src.tuning.problems import schedule_problem as schedule_problem
from wmr_jax._src.tuning.saved import load_tuned as load_tuned
from wmr_jax._src.tuning.saved import tuned_json as tuned_json
from wmr_jax._src.tuning.search import SearchResult as SearchResult
from wmr_jax._src.tuning.search import cma_es_search as cma_es_search
from wmr_jax._src.tuning.search import random_search as random_search
from wmr_jax._src.tuning.trainer import TrainState as TrainState
from wmr_jax._src.tuning.trainer import TuneResult as TuneResult
from wmr_jax._src.tuning.trainer import restore_state as restore_state
from wmr_jax._src.tuning.trainer import state_arrays as state_arrays
from wmr_jax._src.tuning.training import TuneConfig as TuneConfig
from wmr_jax._src.tuning.training import init_state as init_state
from wmr_jax._src.tuning.training import run_identity as run_identity
from wmr_jax._src.tuning.training import train as train
from wmr_jax._src.tuning.training import training_poses as training_poses
