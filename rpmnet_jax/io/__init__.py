"""Files in and out, for every layer: point clouds (:mod:`~rpmnet_jax.io.clouds`; one module per format: ``ply``,
``pcd``, ``text``, ``las``, ``e57``; what each column is: ``columns``), transforms and candidates,
and scan poses in Stanford ``.conf`` files (:mod:`~rpmnet_jax.io.poses`)."""
