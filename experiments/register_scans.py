"""`python -m experiments.register_scans` from a checkout: the same as the installed `rpmnet-register-scans` (:mod:`rpmnet_jax.cli.register_scans`)."""

from rpmnet_jax.cli.register_scans import entry

if __name__ == "__main__":
    entry()
