#!/usr/bin/env bash
# Whether aarch64 gives x86-64's answers to the bit: the sample image's classical and learned
# alignments and a 2009 -> 2020 eval of N poses (default 4), run by this host's build
# (build/release) and by the aarch64 build under qemu-user (build/aarch64, made by
# scripts/test-aarch64.sh), their JSON compared value by value but the times.
#   bash scripts/same-bytes-aarch64.sh [N]     (about 3 minutes under qemu for N = 4)
set -euo pipefail
cd "$(dirname "$0")/.."
x86=build/release/tools/terralign/terralign
arm=${ARM_BUILD:-build/aarch64}/tools/terralign/terralign
for b in "$x86" "$arm"; do
  [ -x "$b" ] || { echo "same-bytes: $b is missing (scripts/test.sh builds the first, scripts/test-aarch64.sh the second)"; exit 2; }
done
out=${OUT:-build/same-bytes}
count=${1:-4}
cam=data/cameras/uav_752x480.json
map=data/naip_west/map.json
prior="487443 5207438 1366 0.0087 0.99996 0.0013 0"
run() {  # run DIR PROGRAM...: the jobs, into DIR
  local dir=$1
  shift
  mkdir -p "$dir"
  "$@" render --map $map --camera $cam --pose "487455 5207430 1372 0.0087 0.99996 0.0013 0" --layers 2016 \
    --out "$dir/camera" >/dev/null
  "$@" align --map $map --camera $cam --image "$dir/camera/2016.png" --layer 2016 --prior "$prior" >"$dir/align.json"
  "$@" align --map $map --camera $cam --image "$dir/camera/2016.png" --layer 2016 --method nn --prior "$prior" \
    >"$dir/align_nn.json"
  "$@" eval --map $map --camera $cam --ref-layer 2009 --query-layer 2020 --count "$count" --seed 1 \
    --altitude 700:900 --tilt 10 --methods init,classic:20,nn:20 --json "$dir/eval.json" >/dev/null 2>&1
}
run "$out/x86-64" "$x86"
run "$out/aarch64" qemu-aarch64 "$arm"
cmp "$out/x86-64/camera/2016.png" "$out/aarch64/camera/2016.png" && echo "camera image: the same bytes"
python3 - "$out" <<'PY'
import json, sys
out = sys.argv[1]
def strip(o):  # times (keys "ms", "*_ms", "seconds") and the command line differ by design
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if not (k == "ms" or k.endswith("_ms") or k in ("seconds", "command"))}
    return [strip(v) for v in o] if isinstance(o, list) else o
def leaves(o, path=""):
    if isinstance(o, dict):
        for k in sorted(o): yield from leaves(o[k], path + "/" + k)
    elif isinstance(o, list):
        for i, v in enumerate(o): yield from leaves(v, f"{path}[{i}]")
    else:
        yield path, o
bad = 0
for name in ("align.json", "align_nn.json", "eval.json"):
    a = dict(leaves(strip(json.load(open(f"{out}/x86-64/{name}")))))
    b = dict(leaves(strip(json.load(open(f"{out}/aarch64/{name}")))))
    diff = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    print(f"{name}: {len(a)} values, {len(diff)} differ" + "".join(f"\n  {k}: {a.get(k)!r} | {b.get(k)!r}" for k in diff[:5]))
    bad += len(diff)
sys.exit(1 if bad else 0)
PY
