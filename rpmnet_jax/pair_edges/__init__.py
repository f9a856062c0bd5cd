"""Pair edges between scans: one pair's edge measured (``edges``: classical, network, ICP), many pairs run as tasks
in process or on Dask (``pair_engine``), each result kept on disk (``pair_cache``)."""
