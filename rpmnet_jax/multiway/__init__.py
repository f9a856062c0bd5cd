"""Many scans into one frame: :func:`rpmnet_jax.align_scans` (``scan_alignment``, its stages ``preparation``,
``edge_graph``, ``placement``, ``refinement``), which pairs to register (``candidate_pairs``), the edge doubt model
(``edge_doubt``), sizes and sensors (``sizes``) and its options (``options``). The pair edges and the engine that
runs them are :mod:`rpmnet_jax.pair_edges`; the pose graph and the joint refinement :mod:`rpmnet_jax.pose_graphs`."""
