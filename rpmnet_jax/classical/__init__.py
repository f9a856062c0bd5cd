"""The classical registration parts (NumPy/Numba, the RANSAC verification in JAX): FPFH features (``fpfh``), their
RANSAC hypotheses (``feature_ransac``), robust point-to-plane ICP (``icp``) and scoring a transform (``scoring``).
Knows nothing of the network."""
