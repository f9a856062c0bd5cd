"""Many scans into one frame: :func:`rpmnet_jax.align_scans` (``scan_alignment``) over pairwise edges
(``edges``) and a robust pose graph (``pose_graph``); its options (``options``)."""
