"""The command line's jobs: `slps-jax paper` (`paper`)."""
