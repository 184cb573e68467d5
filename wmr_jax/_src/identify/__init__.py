"""Identify the true robot from its logs (docs/model.md §10)."""
