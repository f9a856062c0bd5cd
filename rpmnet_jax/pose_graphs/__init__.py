"""Poses of many scans from what was measured between them: the robust SE(3) pose graph on GTSAM (``pose_graph``)
and the multi-view point-to-plane refinement of all poses together (``joint_refine``)."""
