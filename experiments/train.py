"""`python -m experiments.train` from a checkout: the same as the installed `rpmnet-train` (:mod:`rpmnet_jax.cli.train`)."""

from rpmnet_jax.cli.train import entry

if __name__ == "__main__":
    entry()
