"""Boundary checks: every user input is checked here, in plain Python, before tracing.

Each check names the argument, the value it got and what is allowed, and
raises ``ValueError``; the rest of the package calls these and has no checks
of its own. Values that are JAX tracers (a caller running the library inside
their own ``jit`` or ``grad``) cannot be inspected and pass through unchecked.
"""

from wmr_jax._src.checks.arrays import (
    Parameters,
    as_float_tree,
    batch_sizes,
    common_batch_size,
    field_values,
    list_as_array,
    lists_to_arrays,
    require,
    require_finite_runs,
    require_one_batch_size,
    require_representable,
    require_unbatched,
)
from wmr_jax._src.checks.poses import (
    HEADING_REDUCE_ABOVE,
    MAX_HEADING,
    as_pose_array,
    as_poses,
    position_limit,
    reduce_heading,
)
from wmr_jax._src.checks.values import (
    _FLOAT64_HINT as _FLOAT64_HINT,
)
from wmr_jax._src.checks.values import (
    MAX_STEPS,
    MAX_TEMPERATURE,
    MIN_TEMPERATURE,
    array_kind,
    check_bool,
    check_budget,
    check_callable,
    check_dt,
    check_folder,
    check_int,
    check_key,
    check_number,
    check_path,
    check_substeps,
    check_temperature,
    described,
    float_dtype,
    is_traced,
    real_array,
    require_concrete,
)

__all__ = [
    "HEADING_REDUCE_ABOVE",
    "MAX_HEADING",
    "MAX_STEPS",
    "MAX_TEMPERATURE",
    "MIN_TEMPERATURE",
    "Parameters",
    "array_kind",
    "as_float_tree",
    "as_pose_array",
    "as_poses",
    "batch_sizes",
    "check_bool",
    "check_budget",
    "check_callable",
    "check_dt",
    "check_folder",
    "check_int",
    "check_key",
    "check_number",
    "check_path",
    "check_substeps",
    "check_temperature",
    "common_batch_size",
    "described",
    "field_values",
    "float_dtype",
    "is_traced",
    "list_as_array",
    "lists_to_arrays",
    "position_limit",
    "real_array",
    "reduce_heading",
    "require",
    "require_concrete",
    "require_finite_runs",
    "require_one_batch_size",
    "require_representable",
    "require_unbatched",
]
