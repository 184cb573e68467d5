"""Engines of the experiments; each returns values and writes no files.

The paper's figures, pose-space maps, waypoint chains, robustness Monte
Carlo (``study_horizon`` and ``robot_defaults`` say what runs on your
robot) and the benchmark; ``wmr_jax.report`` draws and saves their results.
"""

from wmr_jax._src.sim.sensing.disturbances import STANDARD_CONDITIONS as STANDARD_CONDITIONS
from wmr_jax._src.sim.sensing.disturbances import STANDARD_MISMATCH as STANDARD_MISMATCH
from wmr_jax._src.sim.sensing.disturbances import Disturbance as Disturbance
from wmr_jax._src.sim.sensing.disturbances import draw_disturbances as draw_disturbances
from wmr_jax._src.sim.sensing.disturbances import sample_disturbance as sample_disturbance
from wmr_jax._src.sim.sensing.estimators import EKF as EKF
from wmr_jax._src.sim.sensing.estimators import ESTIMATORS as ESTIMATORS
from wmr_jax._src.sim.sensing.estimators import OBSERVER as OBSERVER
from wmr_jax._src.sim.sensing.estimators import EKFParams as EKFParams
from wmr_jax._src.sim.sensing.estimators import Estimator as Estimator
from wmr_jax._src.sim.sensing.estimators import ObserverParams as ObserverParams
from wmr_jax._src.sim.sensing.loop import ClosedLoop as ClosedLoop
from wmr_jax._src.sim.sensing.loop import disturbed_metrics as disturbed_metrics
from wmr_jax._src.sim.sensing.loop import disturbed_rollout as disturbed_rollout
from wmr_jax._src.studies.bench import CASES as CASES
from wmr_jax._src.studies.bench import BenchConfig as BenchConfig
from wmr_jax._src.studies.bench import numpy_final_poses as numpy_final_poses
from wmr_jax._src.studies.bench import run_benchmark as run_benchmark
from wmr_jax._src.studies.conditions import evaluate_loop as evaluate_loop
from wmr_jax._src.studies.conditions import noise_curve as noise_curve
from wmr_jax._src.studies.conditions import standard_conditions as standard_conditions
from wmr_jax._src.studies.maps import COMPARISON_RUNS as COMPARISON_RUNS
from wmr_jax._src.studies.maps import DEFAULT_HEADINGS_DEG as DEFAULT_HEADINGS_DEG
from wmr_jax._src.studies.maps import MapStudy as MapStudy
from wmr_jax._src.studies.maps import PoseGrid as PoseGrid
from wmr_jax._src.studies.maps import PoseMetrics as PoseMetrics
from wmr_jax._src.studies.maps import compare_controllers as compare_controllers
from wmr_jax._src.studies.maps import evaluate_poses as evaluate_poses
from wmr_jax._src.studies.maps import map_study as map_study
from wmr_jax._src.studies.maps import pose_grid as pose_grid
from wmr_jax._src.studies.maps import summarize as summarize
from wmr_jax._src.studies.paper import Fig7Runs as Fig7Runs
from wmr_jax._src.studies.paper import PaperCase as PaperCase
from wmr_jax._src.studies.paper import PaperRuns as PaperRuns
from wmr_jax._src.studies.paper import fig6_curve as fig6_curve
from wmr_jax._src.studies.paper import fig7_runs as fig7_runs
from wmr_jax._src.studies.paper import paper_runs as paper_runs
from wmr_jax._src.studies.paper import residual_bound as residual_bound
from wmr_jax._src.studies.paper import run_table as run_table
from wmr_jax._src.studies.robustness import DEFAULT_NOISE_DEG as DEFAULT_NOISE_DEG
from wmr_jax._src.studies.robustness import DEFAULT_NOISE_XY as DEFAULT_NOISE_XY
from wmr_jax._src.studies.robustness import LATE_SHARE as LATE_SHARE
from wmr_jax._src.studies.robustness import ROBUSTNESS_CONDITIONS as ROBUSTNESS_CONDITIONS
from wmr_jax._src.studies.robustness import monte_carlo as monte_carlo
from wmr_jax._src.studies.robustness import robot_defaults as robot_defaults
from wmr_jax._src.studies.robustness import robustness_study as robustness_study
from wmr_jax._src.studies.robustness import settled_at_horizon as settled_at_horizon
from wmr_jax._src.studies.robustness import study_horizon as study_horizon
from wmr_jax._src.studies.waypoints import SOCCER_WAYPOINTS_DEG as SOCCER_WAYPOINTS_DEG
from wmr_jax._src.studies.waypoints import ChainRun as ChainRun
from wmr_jax._src.studies.waypoints import SoccerRun as SoccerRun
from wmr_jax._src.studies.waypoints import SoccerStudy as SoccerStudy
from wmr_jax._src.studies.waypoints import TrackRun as TrackRun
from wmr_jax._src.studies.waypoints import batch_chain_rollout as batch_chain_rollout
from wmr_jax._src.studies.waypoints import batch_track_rollout as batch_track_rollout
from wmr_jax._src.studies.waypoints import chain_rollout as chain_rollout
from wmr_jax._src.studies.waypoints import soccer_study as soccer_study
from wmr_jax._src.studies.waypoints import soccer_waypoints as soccer_waypoints
from wmr_jax._src.studies.waypoints import track_rollout as track_rollout
