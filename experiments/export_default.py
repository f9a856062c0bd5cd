"""Export a training run's parameters as the package's shipped model (official names, ``.npz``).

    python -m experiments.export_default --workdir runs/default --info '{"command": "..."}'
"""

import argparse
import json
import os

import numpy as np

from rpmnet_jax import train as training
from rpmnet_jax.weights import convert
from rpmnet_jax.weights import loading


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workdir", required=True, help="training workdir (its best checkpoint, else the latest)")
    p.add_argument("--out", default=loading.DEFAULT_WEIGHTS)
    p.add_argument("--info", default="{}", help="JSON merged into the model card written beside the weights")
    a = p.parse_args(argv)
    params = training.restore_params(a.workdir)
    np.savez_compressed(a.out, **convert.params_to_torch(params))
    with open(os.path.join(a.workdir, "config.json")) as f:
        info = {"train_config": json.load(f)}
    info.update(json.loads(a.info))
    with open(os.path.splitext(a.out)[0] + ".json", "w") as f:
        json.dump(info, f, indent=2)
    print(f"wrote {a.out} ({os.path.getsize(a.out) / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
