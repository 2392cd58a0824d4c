"""d2c_jax: D2C outcome-directed curriculum RL end to end in JAX/MJX."""
