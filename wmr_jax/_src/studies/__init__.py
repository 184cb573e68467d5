"""Studies built on the simulation: paper figures, maps, sweeps, robustness, waypoints, bench."""
