"""The model: parameters, robots, control laws and dynamics (docs/model.md §2–§5)."""
