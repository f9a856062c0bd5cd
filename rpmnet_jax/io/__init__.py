"""Files in and out, for every layer: point clouds (:mod:`~rpmnet_jax.io.clouds`), transforms and candidates,
and scan poses in Stanford ``.conf`` files (:mod:`~rpmnet_jax.io.poses`)."""
