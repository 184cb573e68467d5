"""The reporting layer: figures, GIFs, Markdown tables and result files.

It draws and writes what the simulator, ``wmr_jax.studies`` and
``wmr_jax.tuning`` return, and simulates nothing itself: a GIF draws runs recorded
by ``batch_rollout`` (``write_gif``). Every file is written atomically.
"""

from wmr_jax._src.io import DamagedFileError as DamagedFileError
from wmr_jax._src.io import atomic_write_bytes as atomic_write_bytes
from wmr_jax._src.io import atomic_write_json as atomic_write_json
from wmr_jax._src.io import atomic_write_npz as atomic_write_npz
from wmr_jax._src.io import atomic_write_text as atomic_write_text
from wmr_jax._src.io import load_arrays as load_arrays
from wmr_jax._src.io import remove_stale_temporaries as remove_stale_temporaries
from wmr_jax._src.io import save_arrays as save_arrays
from wmr_jax._src.io import save_figure as save_figure
from wmr_jax._src.report.animation import frame_timing as frame_timing
from wmr_jax._src.report.animation import write_gif as write_gif
from wmr_jax._src.report.bench import bench_table as bench_table
from wmr_jax._src.report.figures import path_figure as path_figure
from wmr_jax._src.report.figures import plot_paths as plot_paths
from wmr_jax._src.report.figures import plot_wheel_speeds as plot_wheel_speeds
from wmr_jax._src.report.maps import comparison_table as comparison_table
from wmr_jax._src.report.maps import map_figure as map_figure
from wmr_jax._src.report.maps import save_comparison as save_comparison
from wmr_jax._src.report.maps import save_map_study as save_map_study
from wmr_jax._src.report.maps import winner_figure as winner_figure
from wmr_jax._src.report.paper import paper_summary_table as paper_summary_table
from wmr_jax._src.report.paper import save_fig7 as save_fig7
from wmr_jax._src.report.paper import save_paper as save_paper
from wmr_jax._src.report.robustness import ROBUSTNESS_COLUMNS as ROBUSTNESS_COLUMNS
from wmr_jax._src.report.robustness import robustness_figure as robustness_figure
from wmr_jax._src.report.robustness import robustness_table as robustness_table
from wmr_jax._src.report.robustness import standard_figure as standard_figure
from wmr_jax._src.report.robustness import write_robustness as write_robustness
from wmr_jax._src.report.robustness import write_standard_conditions as write_standard_conditions
from wmr_jax._src.report.tables import markdown_table as markdown_table
from wmr_jax._src.report.tuning import evaluation_table as evaluation_table
from wmr_jax._src.report.tuning import tuning_curve as tuning_curve
from wmr_jax._src.report.waypoints import soccer_figure as soccer_figure
from wmr_jax._src.report.waypoints import write_soccer as write_soccer
