"""Reports a person opens: one self-contained HTML page per run, the clouds in 3-D (a small WebGL viewer of
this package, no network) beside the run's numbers (:mod:`~rpmnet_jax.report.pages`). An output layer like
``cli/plots``: it takes NumPy arrays and plain numbers and imports nothing of the pipeline."""
