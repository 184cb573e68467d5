"""Gain tuning under ``k_r + L k_θ ≤ V_max``: the feasible set, the loss, the trainer.

``train`` runs Adam on a relaxed arrival-time loss through the law's smooth
relaxation and judges the result with the hard law against the paper's
feasible gains and a random search of the same wall time; it reports through
``progress_fn`` and writes no files. ``tune`` (the ``wmr-jax tune`` command
as a function) also writes the results and resumable checkpoints to a folder.
See ``docs/model.md §3`` (the gains and their ranges) and ``§6`` (the poses
and the arrival time).
"""

from wmr_jax._src.cli.tune import CHECKPOINT_NAME as CHECKPOINT_NAME
from wmr_jax._src.cli.tune import tune as tune
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
from wmr_jax._src.tuning.search import SearchResult as SearchResult
from wmr_jax._src.tuning.search import random_search as random_search
from wmr_jax._src.tuning.training import TrainState as TrainState
from wmr_jax._src.tuning.training import TuneConfig as TuneConfig
from wmr_jax._src.tuning.training import TuneResult as TuneResult
from wmr_jax._src.tuning.training import init_state as init_state
from wmr_jax._src.tuning.training import restore_state as restore_state
from wmr_jax._src.tuning.training import run_identity as run_identity
from wmr_jax._src.tuning.training import state_arrays as state_arrays
from wmr_jax._src.tuning.training import train as train
from wmr_jax._src.tuning.training import training_poses as training_poses
