#!/usr/bin/env bash
# The GPU run: for a machine with an NVIDIA GPU and JAX with CUDA installed; needs no network, only this checkout.
#
#   benchmarks/gpu_run.sh [--tiny] [--torch-src PATH/TO/RPMNet/src] [-- more compare_torch.py flags]
#
# 1. A device line (what JAX runs on); without a GPU it stops, unless --tiny.
# 2. The parity test (python -m pytest -q tests/parity_test.py) when RPMNET_FIXTURES points at the fixtures
#    (../shared does not travel with the checkout: carry a copy inside it); otherwise a "skipped" line.
# 3. benchmarks/compare_torch.py: our inference at 512/1024/2048 points, B=1 and B=8 (with the
#    official-structure rows), and the training step (B=8, 717 points, 2 iterations, fused and autodiff); the
#    official model on CUDA too when --torch-src is given and torch with CUDA imports.
# Prints JSON lines (one per measurement, each with its device) and writes them to $OUT/gpu_run.jsonl, with the
# table (gpu_compare.md), plot and pytest log, when OUT is set (else under ${TMPDIR:-/tmp}/rpmnet_gpu_run).
# --tiny (or RPMNET_BENCH_TINY=1): a test of this script on CPU: 64/128 points, B=1/2, a 64-point B=2 training
# step, 1 repeat, only the parity test's grouping case, the official model on the CPU when there is no CUDA.
set -uo pipefail
cd "$(dirname "$0")/.."

tiny=${RPMNET_BENCH_TINY:-0}
torch_src=""
extra=()
while [ $# -gt 0 ]; do
    case "$1" in
        --tiny) tiny=1 ;;
        --torch-src) torch_src=$2; shift ;;
        --) shift; extra=("$@"); break ;;
        -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
        *) echo "gpu_run: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
    shift
done
[ "$tiny" = 0 ] || tiny=1

out=${OUT:-${TMPDIR:-/tmp}/rpmnet_gpu_run}
mkdir -p "$out"
log="$out/gpu_run.jsonl"
: > "$log"
say() { echo "$1"; echo "$1" >> "$log"; }
# json KEY VALUE ...: one JSON object (whole numbers as numbers, the rest as strings)
json() { python -c 'import json, sys; a = sys.argv[1:]; v = lambda s: int(s) if s.lstrip("-").isdigit() else s
print(json.dumps({k: v(x) for k, x in zip(a[::2], a[1::2])}))' "$@"; }

device_line=$(python -c '
import json, os, jax
d = jax.devices()
print(json.dumps({"task": "device", "device": f"{d[0].platform}:{d[0].device_kind}", "devices": len(d),
                  "jax": jax.__version__, "matmul_precision": os.environ.get("JAX_DEFAULT_MATMUL_PRECISION", "default")}))
') || { echo "gpu_run: jax does not import" >&2; exit 1; }
say "$device_line"
device=$(python -c 'import json, sys; print(json.loads(sys.argv[1])["device"])' "$device_line")
if [ "$tiny" = 0 ] && [[ "$device" != gpu:* && "$device" != cuda:* ]]; then
    echo "gpu_run: JAX runs on $device, not a GPU (JAX with CUDA installed?); --tiny tests this script on CPU" >&2
    exit 1
fi

fixtures=${RPMNET_FIXTURES:-}
parity_failed=0
if [ -n "$fixtures" ] && ls "$fixtures"/parity_*.npz >/dev/null 2>&1 && python -c "import pytest" 2>/dev/null; then
    target=tests/parity_test.py
    [ "$tiny" = 1 ] && target=tests/parity_test.py::test_grouping_and_ppf
    start=$(date +%s)
    if python -m pytest -q -p no:cacheprovider "$target" > "$out/parity.log" 2>&1; then status=passed; else status=failed; fi
    [ "$status" = passed ] || parity_failed=1
    say "$(json task parity status "$status" tests "$target" device "$device" summary "$(tail -n 1 "$out/parity.log")" \
        seconds "$(( $(date +%s) - start ))" log "$out/parity.log")"
elif [ -z "$fixtures" ] || ! ls "$fixtures"/parity_*.npz >/dev/null 2>&1; then
    say "$(json task parity status skipped device "$device" reason "no parity_*.npz at RPMNET_FIXTURES='$fixtures' (../shared does not travel: carry a copy of shared/fixtures in the checkout and set RPMNET_FIXTURES to it)")"
else
    say "$(json task parity status skipped device "$device" reason "pytest is not installed")"
fi

args=(--points 512 1024 2048 --batch 1 8)
[ "$tiny" = 1 ] && args=(--points 64 128 --batch 1 2 --repeats 1 --train-repeats 1 --train-points 64
                         --train-batch 2 --check-points 64)
if [ -n "$torch_src" ]; then
    if python -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)' 2>/dev/null; then
        args+=(--torch-src "$torch_src" --torch-device cuda)
    elif [ "$tiny" = 1 ] && python -c 'import torch' 2>/dev/null; then
        args+=(--torch-src "$torch_src" --torch-device cpu)
    else
        say "$(json task official status skipped reason "torch with CUDA does not import here")"
    fi
fi
python benchmarks/compare_torch.py "${args[@]}" "${extra[@]}" --out-md "$out/gpu_compare.md" \
    --out-png "$out/gpu_compare.png" --out-jsonl "$out/gpu_compare.jsonl" | tee -a "$log"
rc=${PIPESTATUS[0]}
say "$(json task done compare_torch_exit "$rc" parity_failed "$parity_failed" out "$out")"
[ "$rc" = 0 ] && [ "$parity_failed" = 0 ]
