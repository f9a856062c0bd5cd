"""Host-side geometry of point clouds (NumPy/SciPy/Numba): cleaning and sampling (``cloud``, ``sampling``), the
k-d tree (``kdtree``), normals, sensors and free space (``sensors``, ``visibility``), a common shift
(``offsets``) and the compiled loops' threads (``threads``). Knows nothing of the network."""
