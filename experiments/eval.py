"""`python -m experiments.eval` from a checkout: the same as the installed `rpmnet-eval` (:mod:`rpmnet_jax.cli.evaluate`)."""

from rpmnet_jax.cli.evaluate import entry

if __name__ == "__main__":
    entry()
