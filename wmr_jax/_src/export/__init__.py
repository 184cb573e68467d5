"""The tuned loop as C: code generation, compilation and the host-side loop that judges it."""
