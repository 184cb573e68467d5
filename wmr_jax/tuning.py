"""Gain tuning under ``k_r + L k_θ ≤ V_max``: the feasible set, the loss, the trainer.

``train`` runs Adam on a relaxed arrival-time loss and judges the result with
the hard law; ``tune`` (``wmr-jax tune`` as a function) also writes the results
and resumable checkpoints; ``tune_robust`` tunes a law with its estimator
through disturbances; ``compare`` runs the gradient against CMA-ES and random
search at equal CPU time (docs/model.md §3, §6, §8).
"""

from wmr_jax._src.model.controllers.schedule import SCHEDULE as SCHEDULE
from wmr_jax._src.model.controllers.schedule import ScheduleParams as ScheduleParams
from wmr_jax._src.model.controllers.schedule import knot_radii as knot_radii
from wmr_jax._src.studies.optimal import TimeBounds as TimeBounds
from wmr_jax._src.studies.optimal import bound_ratios as bound_ratios
from wmr_jax._src.studies.optimal import time_bounds as time_bounds
from wmr_jax._src.tuning.compare import compare as compare
from wmr_jax._src.tuning.estimation import robust_gains as robust_gains
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
from wmr_jax._src.tuning.robust import RobustConfig as RobustConfig
from wmr_jax._src.tuning.robust import robust_score as robust_score
from wmr_jax._src.tuning.robust import tune_robust as tune_robust
from wmr_jax._src.tuning.run import CHECKPOINT_NAME as CHECKPOINT_NAME
from wmr_jax._src.tuning.run import tune as tune
from wmr_jax._src.tuning.saved import load_tuned as load_tuned
from wmr_jax._src.tuning.saved import tuned_json as tuned_json
from wmr_jax._src.tuning.saved import tuning_of as tuning_of
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
