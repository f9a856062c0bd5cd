"""`python -m experiments.eval_scans` from a checkout: the same as the installed `rpmnet-eval-scans` (:mod:`rpmnet_jax.cli.eval_scans`)."""

from rpmnet_jax.cli.eval_scans import entry

if __name__ == "__main__":
    entry()
