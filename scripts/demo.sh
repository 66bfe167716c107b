#!/usr/bin/env bash
# The main job on the sample data shipped in the repo. On a fresh Debian 12 machine it
# installs what it needs, builds terralign, then:
#  1. describes the sample maps (terralign info);
#  2. renders the NAIP map from a pose: every year's colour and the metric depth;
#  3. plays the camera: renders the 2016 layer from a "true" pose as the camera image, and
#     localises it with terralign align from a prior 12 m and 1.5 degrees off;
#  4. runs the paper's evaluation on 20 poses, same year and across years (2016 -> 2017, and
#     2009 -> 2020 with the learned tracker beside the classical one), printing the tables and
#     writing the overlay figures (out/demo/overlays*: red the reference, green-blue the camera
#     image seen through each method's pose);
#  5. the map as a map of several years: 2020's images aligned to 2016, and to 2012 and then
#     2009 only where the alignment before failed (eval prints which year answered).
# Outputs go to out/demo (or the folder given as the first argument).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)" --target terralign_cli
tl=build/release/tools/terralign/terralign
out=${1:-out/demo}
mkdir -p "$out"
cam=data/cameras/uav_752x480.json
naip=data/naip_west/map.json
set -x
$tl info --map $naip
$tl info --map data/christchurch/000121.json
$tl render --map $naip --camera $cam --pose "487450 5207437 1370 0 1 0 0" --out "$out/render"
# The camera image: 2016 seen from the true pose 487455 5207430 1372 (nadir, heading 0).
$tl render --map $naip --camera $cam --pose "487455 5207430 1372 0 1 0 0" --layers 2016 --out "$out/camera"
$tl align --map $naip --camera $cam --image "$out/camera/2016.png" --layer 2016 \
  --prior "487443 5207438 1366 0.0087 0.99996 0.0013 0" | tee "$out/align.json"
# The learned tracker on the same image.
$tl align --map $naip --camera $cam --image "$out/camera/2016.png" --layer 2016 --method nn \
  --prior "487443 5207438 1366 0.0087 0.99996 0.0013 0" | tee "$out/align_nn.json"
$tl eval --map $naip --camera $cam --ref-layer 2016 --query-layer 2016 --count 20 --seed 1 \
  --altitude 700:900 --tilt 10 --json "$out/eval_2016_2016.json" --overlays "$out/overlays"
$tl eval --map $naip --camera $cam --ref-layer 2016 --query-layer 2017 --count 20 --seed 1 \
  --altitude 700:900 --tilt 10 --methods init,classic:20,nn:20 --json "$out/eval_2016_2017.json"
$tl eval --map $naip --camera $cam --ref-layer 2009 --query-layer 2020 --count 20 --seed 1 \
  --altitude 700:900 --tilt 10 --methods init,classic:20,classic:50,nn:20 --json "$out/eval_2009_2020.json" \
  --overlays "$out/overlays_2009_2020"
$tl eval --map $naip --camera $cam --ref-layer 2016,2012,2009 --query-layer 2020 --count 20 --seed 1 \
  --altitude 700:900 --tilt 10 --methods init,nn:20 --json "$out/eval_layers_2020.json"
