"""Write the synthetic dataset in the ModelNet40 HDF5 layout.

    python -m experiments.make_synthetic --out data/synthetic --num-train 400 --num-test 100
"""

import argparse
import time

from rpmnet_jax.data import synthetic


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="output folder (a modelnet40_ply_hdf5_2048/ is made in it)")
    parser.add_argument("--num-train", type=int, default=400, help="training shapes (default 400)")
    parser.add_argument("--num-test", type=int, default=100, help="test shapes (default 100)")
    parser.add_argument("--num-points", type=int, default=2048, help="points per shape (default 2048)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.num_train < 0 or args.num_test < 0 or args.num_points < 1:
        parser.error("--num-train/--num-test must be >= 0 and --num-points >= 1")
    t0 = time.time()
    folder = synthetic.write_dataset(args.out, args.num_train, args.num_test, args.seed, args.num_points)
    print(f"wrote {args.num_train} train + {args.num_test} test shapes to {folder} in {time.time() - t0:.1f}s")


if __name__ == "__main__":
    main()
