"""Host-side geometry of point clouds (NumPy/SciPy, the RANSAC verification in JAX): cleaning and sampling
(``cloud``, ``sampling``), normals, FPFH features and RANSAC hypotheses (``fpfh``, ``feature_ransac``), robust
point-to-plane ICP (``icp``) and scoring a transform (``scoring``). Knows nothing of the network."""
