"""Sensing in the loop: disturbances (docs/model.md §7), estimators and the disturbed loop (§9)."""
