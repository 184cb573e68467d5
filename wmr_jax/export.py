"""The tuned loop as a C controller for the robot: generate, compile, and judge it.

``c_sources`` turns a ``ClosedLoop`` (``load_tuned``) into C99 sources with
the tuned constants baked in (``write_sources`` writes them);
``compile_controller`` builds and wraps them with ``ctypes``;
``compiled_metrics`` and ``evaluate_compiled`` run and judge the compiled
controller in the disturbed loop (docs/model.md §7, §9). docs/deploy.md takes
the files from here to the robot.
"""

from wmr_jax._src.export.codegen import MAX_LATENCY as MAX_LATENCY
from wmr_jax._src.export.codegen import REALS as REALS
from wmr_jax._src.export.codegen import CSources as CSources
from wmr_jax._src.export.codegen import c_sources as c_sources
from wmr_jax._src.export.codegen import write_sources as write_sources
from wmr_jax._src.export.compiled import CFLAGS as CFLAGS
from wmr_jax._src.export.compiled import CompiledController as CompiledController
from wmr_jax._src.export.compiled import compile_controller as compile_controller
from wmr_jax._src.export.compiled import compiler as compiler
from wmr_jax._src.export.compiled import sanitizers_work as sanitizers_work
from wmr_jax._src.export.host import compiled_metrics as compiled_metrics
from wmr_jax._src.export.host import evaluate_compiled as evaluate_compiled
from wmr_jax._src.export.host import exported_loop as exported_loop
from wmr_jax._src.export.host import read_metadata as read_metadata
