"""Reports a person opens: one self-contained HTML page per run, the clouds in 3-D (a small WebGL viewer of
this package, no network) beside the run's numbers (:mod:`~rpmnet_jax.report.pages`), under a banner that says
why to doubt the run (:mod:`~rpmnet_jax.report.alerts`), every number written as the CLIs print it
(:mod:`~rpmnet_jax.report.formats`). An output layer like ``cli/plots``: it takes NumPy arrays and plain numbers
and imports nothing of the pipeline."""
