"""Many runs at once: the grid of cases (Dask or in-process), the penalty-number and robustness grids,
judging their results."""
