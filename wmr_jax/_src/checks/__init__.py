"""Boundary checks of user input, in plain Python before tracing.

Each names the argument, the value it got and what is allowed, and raises
``ValueError``; JAX tracers cannot be inspected and pass unchecked.
"""

from wmr_jax._src.checks.arrays import Parameters as Parameters
from wmr_jax._src.checks.arrays import as_float_tree as as_float_tree
from wmr_jax._src.checks.arrays import batch_sizes as batch_sizes
from wmr_jax._src.checks.arrays import common_batch_size as common_batch_size
from wmr_jax._src.checks.arrays import field_array as field_array
from wmr_jax._src.checks.arrays import field_values as field_values
from wmr_jax._src.checks.arrays import list_as_array as list_as_array
from wmr_jax._src.checks.arrays import require as require
from wmr_jax._src.checks.arrays import require_finite_runs as require_finite_runs
from wmr_jax._src.checks.arrays import require_one_batch_size as require_one_batch_size
from wmr_jax._src.checks.arrays import require_representable as require_representable
from wmr_jax._src.checks.arrays import require_unbatched as require_unbatched
from wmr_jax._src.checks.poses import MAX_HEADING as MAX_HEADING
from wmr_jax._src.checks.poses import as_pose_array as as_pose_array
from wmr_jax._src.checks.poses import as_poses as as_poses
from wmr_jax._src.checks.poses import position_limit as position_limit
from wmr_jax._src.checks.values import _FLOAT64_HINT as _FLOAT64_HINT
from wmr_jax._src.checks.values import MAX_STEPS as MAX_STEPS
from wmr_jax._src.checks.values import MAX_TEMPERATURE as MAX_TEMPERATURE
from wmr_jax._src.checks.values import array_kind as array_kind
from wmr_jax._src.checks.values import check_bool as check_bool
from wmr_jax._src.checks.values import check_budget as check_budget
from wmr_jax._src.checks.values import check_callable as check_callable
from wmr_jax._src.checks.values import check_dt as check_dt
from wmr_jax._src.checks.values import check_folder as check_folder
from wmr_jax._src.checks.values import check_int as check_int
from wmr_jax._src.checks.values import check_key as check_key
from wmr_jax._src.checks.values import check_number as check_number
from wmr_jax._src.checks.values import check_path as check_path
from wmr_jax._src.checks.values import check_substeps as check_substeps
from wmr_jax._src.checks.values import check_temperature as check_temperature
from wmr_jax._src.checks.values import described as described
from wmr_jax._src.checks.values import float_dtype as float_dtype
from wmr_jax._src.checks.values import is_traced as is_traced
from wmr_jax._src.checks.values import real_array as real_array
from wmr_jax._src.checks.values import require_concrete as require_concrete
