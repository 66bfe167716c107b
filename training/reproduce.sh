#!/usr/bin/env bash
# The learned tracker's default weights, weights/deep_iclk_s16w64.tlw, trained again in one
# command from the file they were trained from (weights/deep_iclk_s16.tlw, committed), and
# compared with the committed file:
#   1. the training data (training/README.md, steps 1 and 7): NAIP's five training years and the
#      Christchurch strip, rendered by `terralign dataset` at half the camera's size;
#   2. step 24's three runs of 1200 steps (s16 widened to s16w64, then two continuations);
#   3. the export with the committed file's note, the agreement threshold calibrated
#      (training/calibrate_sharpness.py), and every tensor and byte compared
#      (training/same_tensors.py, cmp): the verdict. Each run's log is compared with its
#      committed one (training/runs/NAME/log.csv) too, to say where a reproduction that
#      differs parted from it.
#
#   bash training/reproduce.sh [--work DIR] [--check STEPS]
#
# --work DIR (default /work/train): the data, the runs and the weight file; each stage is
# skipped where its result is there, and a run stopped midway resumes from its checkpoint.
# --check STEPS: only the first run's first STEPS steps, whose log (training loss every 50
# steps, validation every 300) is then compared with the committed one
# (training/runs/s16w64/log.csv) line by line, the times aside.
#
# Needs the release build of the README's test command (build/release), Debian's
# python3-torch and python3-matplotlib (`apt-get install python3-torch python3-matplotlib`;
# /usr/bin/python3, not a pyenv python3) and ../shared/data beside the checkout. On two cores:
# about 5 minutes of data, 2.6 hours of training (session 38: 2475, 3360 and 3441 s), 5 minutes
# of calibration; 3.7 GB of data. The whole chain from a network's first step is not
# reproducible by one command: the first runs (sessions 3-33, training/README.md steps 2-20)
# were trained by earlier versions of train_deep.py (four levels at first, one feature channel
# until session 28), each from the file the session before had committed.
set -euo pipefail
cd "$(dirname "$0")/.."
work=/work/train
check=0
while [ $# -gt 0 ]; do
  case "$1" in
    --work) work=${2:?--work needs a directory}; shift 2 ;;
    --check) check=${2:?--check needs a number of steps}; shift 2 ;;
    *) echo "reproduce.sh: unknown argument '$1' (--work DIR, --check STEPS)" >&2; exit 2 ;;
  esac
done
case "$check" in
  ''|*[!0-9]*) echo "reproduce.sh: --check '$check' is not a number of steps" >&2; exit 2 ;;
esac
py=/usr/bin/python3
tl=build/release/tools/terralign/terralign
[ -x "$tl" ] || { echo "reproduce.sh: $tl is not built (the README's test command builds it)" >&2; exit 1; }
$py -c "import torch, matplotlib" 2>/dev/null ||
  { echo "reproduce.sh: $py lacks torch or matplotlib (apt-get install python3-torch python3-matplotlib)" >&2; exit 1; }
shared=../shared/data
for f in naip_nd_2009_2020/naip/m_4709963_se_14_1_20100629.tif whu_cd_christchurch_more_samples; do
  [ -e "$shared/$f" ] || { echo "reproduce.sh: $shared/$f is missing (the shared data beside the checkout)" >&2; exit 1; }
done
mkdir -p "$work/runs"

# A data set written to DIR.part and renamed when whole: a stopped render is redone, never half used.
dataset() {
  local out=$1; shift
  if [ -f "$out/index.csv" ]; then echo "data: $out is there"; return; fi
  rm -rf "$out.part"
  "$tl" dataset "$@" --out "$out.part" > "$out.log" 2>&1 || { echo "reproduce.sh: terralign dataset failed, see $out.log" >&2; exit 1; }
  mv "$out.part" "$out"
  tail -n 1 "$out.log"
}
dataset "$work/naip_376" --map training/naip_train_years.json --camera data/cameras/uav_752x480.json \
  --count 1500 --seed 20261122 --altitude 600:900 --tilt 10 --split-fraction 0.3 --scale 0.5
if [ ! -f "$work/chch_map/christchurch_train.json" ]; then
  rm -rf "$work/chch_map.part"
  $py training/make_christchurch_mosaic.py "$work/chch_map.part"
  mv "$work/chch_map.part" "$work/chch_map"
fi
dataset "$work/chch_376" --map "$work/chch_map/christchurch_train.json" --camera data/cameras/uav_752x480.json \
  --count 600 --seed 20261123 --altitude 45:65 --tilt 10 --split-fraction 0.3 --scale 0.5

# One of step 24's runs (training/README.md): NAME SEED INIT [--widen]. Resumes a stopped run;
# skipped where its last checkpoint is at step 1200.
run() {
  local name=$1 seed=$2 init=$3; shift 3
  local out="$work/runs/$name" stop=()
  [ "$check" -gt 0 ] && stop=(--stop-at "$check")
  if [ "$check" -eq 0 ] && [ -f "$out/last.pt" ] &&
     [ "$($py -c "import sys, torch; print(torch.load(sys.argv[1])['step'])" "$out/last.pt")" = 1200 ]; then
    echo "run $name: done"; return
  fi
  echo "run $name: $out.stdout.txt"
  $py training/train_deep.py --data "$work/naip_376" --extra "$work/chch_376" --extra-p 0.35 --out "$out" \
    --size s16w64 --channels 2 --steps 1200 --batch 4 --iterations 5 --lr 3e-4 --seed "$seed" \
    --val-every 300 --val-count 64 --augment 0.8 --augment-survey 0.5 --gap-power 3 --tilt-prior 3 \
    --init "$init" --resume "${stop[@]}" "$@" >> "$out.stdout.txt" 2>&1 ||
    { echo "reproduce.sh: run $name failed, see $out.stdout.txt" >&2; exit 1; }
}
run s16w64 38 weights/deep_iclk_s16.tlw --widen
# A run's log against the committed one (training/runs/NAME/log.csv), its lines up to step UPTO
# without their time (the last column); prints what differs and returns 1 if anything does.
same_log() {
  local name=$1 upto=$2
  strip() { awk -F, -v n="$upto" 'NR > 1 && $2 <= n { NF = 7; print }' OFS=, "$1"; }
  if diff <(strip "training/runs/$name/log.csv") <(strip "$work/runs/$name/log.csv"); then
    echo "log $name: the committed run's to step $upto ($(strip "$work/runs/$name/log.csv" | wc -l) lines)"
    return 0
  fi
  echo "log $name: differs from training/runs/$name/log.csv (above: < committed, > this run)" >&2
  return 1
}
if [ "$check" -gt 0 ]; then
  same_log s16w64 "$check" && exit 0
  exit 1
fi
run s16w64b 39 "$work/runs/s16w64/last.pt"
run s16w64c 40 "$work/runs/s16w64b/last.pt"

# The export carries the committed file's note, so that the files can match byte for byte.
# Skipped where the file is there and newer than the last run's checkpoint.
out="$work/deep_iclk_s16w64.tlw"
if [ "$out" -nt "$work/runs/s16w64c/last.pt" ]; then
  echo "export: $out is there"
else
  $py training/export_deep.py "$work/runs/s16w64c/last.pt" "$out.part" --note-from weights/deep_iclk_s16w64.tlw
  python3 training/calibrate_sharpness.py --test agreement --count 200 --only "$out.part" > "$out.log" 2>&1 ||
    { echo "reproduce.sh: the calibration failed, see $out.log" >&2; exit 1; }
  tail -n 1 "$out.log"
  mv "$out.part" "$out"
fi
# The logs say where a reproduction parted from the committed one; the file is the verdict.
logs=0
for name in s16w64 s16w64b s16w64c; do same_log "$name" 1200 || logs=1; done
if $py training/same_tensors.py "$out" weights/deep_iclk_s16w64.tlw && cmp "$out" weights/deep_iclk_s16w64.tlw; then
  echo "reproduced: $out is weights/deep_iclk_s16w64.tlw byte for byte"
  [ "$logs" -eq 0 ] || echo "reproduce.sh: the same file, though a log differs (above)" >&2
else
  echo "reproduce.sh: $out differs from weights/deep_iclk_s16w64.tlw (above)" >&2
  exit 1
fi
