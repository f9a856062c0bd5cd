#!/usr/bin/env bash
# The campaign's GPU run: train from the shipped model (or another state) for a fixed wall time on a machine
# that has only this checkout (no ../shared, no network), and bring back the params.
#
#   python -m experiments.pack_training_data --data-root ../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train --out runs/pack
#   experiments/gpu_train.sh [--tiny]        # there; carry runs/pack with the checkout
#
# Settings (environment): PACK (runs/pack), INIT (the state to start from; default the shipped model,
# rpmnet_jax/weights/rpmnet_default.npz: no later campaign state beats it), MINUTES (8: SIGTERM then, which
# saves and stops; the export after it takes ~30 s, inside a 10-minute call), BATCH (8), LR (3e-4, constant),
# SEED (0), VAL_EVERY (500 steps), EXTRA (more experiments.train flags).
# Writes to $OUT (else ${TMPDIR:-/tmp}/rpmnet_gpu_train): params_best.npz (EMA params of the best checkpoint by
# validation Chamfer distance on the pack's validation shapes, a guide: they are 1,280-point copies, not the
# CPU validation set), params_latest.npz (EMA params of the last step), config.json, train.log, summary.json
# (device, steps, seconds, validation lines). Validate both on CPU, then continue with --init-from.
# --tiny: a test of this script on CPU (3 steps of 256 points, 4 validation pairs).
set -uo pipefail
cd "$(dirname "$0")/.."

tiny=0
case "${1:-}" in
    --tiny) tiny=1 ;;
    "") ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    *) echo "gpu_train: unknown argument $1 (see --help)" >&2; exit 2 ;;
esac
pack=${PACK:-runs/pack}
init=${INIT:-rpmnet_jax/weights/rpmnet_default.npz}
minutes=${MINUTES:-8}
out=${OUT:-${TMPDIR:-/tmp}/rpmnet_gpu_train}
work=$(mktemp -d "${TMPDIR:-/tmp}/rpmnet_gpu_work.XXXXXX")
roots=$(ls -d "$pack"/*/ 2>/dev/null | sed 's:/$::' | paste -sd, -)
[ -n "$roots" ] || { echo "gpu_train: no packed data in $pack (python -m experiments.pack_training_data)" >&2; exit 2; }
[ -f "$init" ] || { echo "gpu_train: no state to start from (INIT=$init)" >&2; exit 2; }
mkdir -p "$out"

device=$(python3 -c 'import jax; d = jax.devices()[0]; print(f"{d.platform}:{d.device_kind}")') \
    || { echo "gpu_train: jax does not import" >&2; exit 1; }
echo "gpu_train: jax on $device, data $roots, from $init, $minutes min"
if [ "$tiny" = 0 ] && [[ "$device" != gpu:* && "$device" != cuda:* ]]; then
    echo "gpu_train: JAX runs on $device, not a GPU; --tiny tests this script on CPU" >&2
    exit 1
fi
size=(--num-points 1024 --val-limit 64 --max-steps 1000000 --val-every-steps "${VAL_EVERY:-500}")
[ "$tiny" = 1 ] && size=(--num-points 256 --val-limit 4 --max-steps 3 --val-every-steps 2)

start=$(date +%s)
PYTHONUNBUFFERED=1 timeout -s TERM -k 60 "$((minutes * 60))" python3 -m experiments.train --dataset=partial \
    --data-root "$roots" --workdir "$work/run" --batch-size "${BATCH:-8}" --rot-mag 45 --lr "${LR:-3e-4}" \
    --ema-decay 0.99 --seed "${SEED:-0}" --init-from "$init" --save-every 100 --epochs 100000 --no-progress \
    "${size[@]}" ${EXTRA:-} 2>&1 | tee "$out/train.log"
rc=${PIPESTATUS[0]}
seconds=$(( $(date +%s) - start ))
# 124: the time limit's SIGTERM, after which the run saved and stopped
[ "$rc" = 0 ] || [ "$rc" = 124 ] || { echo "gpu_train: training failed (exit $rc)" >&2; exit 1; }
cp "$work/run/config.json" "$out/"
python3 - "$out" "$work/run" "$device" "$init" "$seconds" <<'EOF' || exit 1
import json, os, re, sys
import numpy as np
from rpmnet_jax.weights import convert, loading
out, run, device, init, seconds = sys.argv[1:]
for name, where in (("params_best.npz", run), ("params_latest.npz", os.path.join(run, "checkpoints", "latest"))):
    np.savez_compressed(os.path.join(out, name), **convert.params_to_torch(loading.restore_params(where)))
lines = open(os.path.join(out, "train.log")).read().splitlines()
val = [(int(m[1]), json.loads(m[2])["err_r_deg_mean"]) for m in
       (re.search(r"step (\d+) validation (\{.*\})", l) for l in lines) if m]
stop = [int(m[1]) for m in (re.search(r"at step (\d+)", l) for l in lines) if m]
summary = {"device": device, "init_from": init, "seconds": int(seconds),
           "steps": max(stop + [s for s, _ in val] + [0]), "validation_err_r_deg_mean": val}
json.dump(summary, open(os.path.join(out, "summary.json"), "w"), indent=1)
print(json.dumps(summary))
EOF
rm -rf "$work"
