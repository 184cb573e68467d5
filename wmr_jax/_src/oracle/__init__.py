"""The plain NumPy implementation of the model that the JAX code is tested against."""
