"""Simulation: the closed-loop step and scan, disturbances, estimators, metrics, sharding."""
