"""Many scans into one frame: :func:`rpmnet_jax.align_scans` (``scan_alignment``) over pairwise edges
(``edges``) and a robust pose graph (``pose_graph``); its options (``options``); the pairs run as tasks, in
process or on Dask (``pair_engine``), and kept on disk (``pair_cache``)."""
