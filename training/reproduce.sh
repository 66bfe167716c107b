#!/usr/bin/env bash
# The learned tracker's two shipped weight files trained again in one command, each compared
# with the committed file, from session 28's s16 file (training/README.md, step 16; in git as
# committed in 3c0722d):
#   1. the training data (training/README.md, steps 1 and 7): NAIP's five training years and the
#      Christchurch strip, rendered by `terralign dataset` at half the camera's size;
#   2. session 31's s16 file: step 17's run of 1200 steps with the anchor loss, from step 16's
#      file, compared with the file as committed in 1ada086 (its threshold calibrated under
#      today's defaults);
#   3. weights/deep_iclk_s16.tlw (the firmware's): step 20's run of 600 steps with the tilt
#      prior, from stage 2's file;
#   4. weights/deep_iclk_s16w64.tlw (the default): step 24's three runs of 1200 steps (stage 3's
#      file widened to s16w64, then two continuations).
# Each stage ends with the export under the committed file's note, the agreement threshold
# calibrated (training/calibrate_sharpness.py), and every tensor and byte compared with the
# committed file (training/same_tensors.py, cmp): the verdict, and a stage that differs stops
# the command. Each run's log is compared with its committed one (training/runs/NAME/log.csv)
# too, to say where a reproduction that differs parted from it.
#
#   bash training/reproduce.sh [--work DIR] [--from STEP] [--check STEPS]
#
# --work DIR (default /work/train): the data, the runs and the weight files; each stage is
# skipped where its result is there, and a run stopped midway resumes from its checkpoint.
# --from STEP: start from the file of training step 16 (the default), 17 (stages 3 and 4, from
# the file committed in 1ada086) or 20 (stage 4 alone, from the committed
# weights/deep_iclk_s16.tlw: session 50's command).
# --check STEPS: only the first run's first STEPS steps, whose log (training loss every 50
# steps, validation every 300 or 400) is then compared with the committed one line by line,
# the times aside. Step 17's log (the first run from step 16) has three loss means 1e-4 from
# the committed ones (their rounding, the tensors the same), so a quick check starts later:
# --from 17 --check 300.
#
# Needs the release build of the README's test command (build/release), Debian's
# python3-torch and python3-matplotlib (`apt-get install python3-torch python3-matplotlib`;
# /usr/bin/python3, not a pyenv python3), ../shared/data beside the checkout and, from step 16
# or 17, the checkout's git history. On two cores: about 5 minutes of data; 50 minutes of
# training for stage 2, 20 for stage 3 and 2.6 hours for stage 4 (session 38: 2475, 3360 and
# 3441 s); 2-5 minutes of calibration a stage; 3.7 GB of data. The chain before step 16 is not
# one command: its runs (sessions 3-28, training/README.md steps 2-16) were trained by earlier
# versions of train_deep.py (four levels at first, one feature channel until session 28), each
# from the file the session before had committed.
set -euo pipefail
cd "$(dirname "$0")/.."
work=/work/train
check=0
from=16
while [ $# -gt 0 ]; do
  case "$1" in
    --work) work=${2:?--work needs a directory}; shift 2 ;;
    --check) check=${2:?--check needs a number of steps}; shift 2 ;;
    --from) from=${2:?--from needs a training step: 16, 17 or 20}; shift 2 ;;
    *) echo "reproduce.sh: unknown argument '$1' (--work DIR, --from STEP, --check STEPS)" >&2; exit 2 ;;
  esac
done
case "$from" in
  16|17|20) ;;
  *) echo "reproduce.sh: --from '$from' is not 16, 17 or 20 (training/README.md's steps)" >&2; exit 2 ;;
esac
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
# The files of steps 16 and 17 from git (1ada086 recalibrated step 17's threshold under the
# tilt prior that became the default then, its tensors unchanged).
step16=3c0722d:weights/deep_iclk_s16.tlw
step17=1ada086:weights/deep_iclk_s16.tlw
mkdir -p "$work/runs"
committed() {  # NAME GIT-OBJECT: the committed file as $work/NAME
  [ -f "$work/$1" ] && return
  git cat-file -e "$2" 2>/dev/null ||
    { echo "reproduce.sh: $2 is not in this checkout's git history (clone the repository, or --from 20)" >&2; exit 1; }
  git show "$2" > "$work/$1.part"
  mv "$work/$1.part" "$work/$1"
}
[ "$from" -eq 20 ] || committed s16_step17.tlw "$step17"
[ "$from" -ne 16 ] || committed s16_step16.tlw "$step16"

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

# A run of training/README.md's steps 17, 20 and 24: NAME SIZE STEPS SEED INIT [ARGS: the
# step's own flags]. Resumes a stopped run; skipped where its last checkpoint is at STEPS.
# Under --check: to step STEPS of --check, then its log compared with the committed one, and
# the command ends.
run() {
  local name=$1 size=$2 steps=$3 seed=$4 init=$5; shift 5
  local out="$work/runs/$name" stop=()
  [ "$check" -gt 0 ] && stop=(--stop-at "$check")
  if [ "$check" -eq 0 ] && [ -f "$out/last.pt" ] &&
     [ "$($py -c "import sys, torch; print(torch.load(sys.argv[1])['step'])" "$out/last.pt")" = "$steps" ]; then
    echo "run $name: done"; return
  fi
  echo "run $name: $out.stdout.txt"
  $py training/train_deep.py --data "$work/naip_376" --extra "$work/chch_376" --extra-p 0.35 --out "$out" \
    --size "$size" --channels 2 --steps "$steps" --batch 4 --iterations 5 --lr 3e-4 --seed "$seed" \
    --val-count 64 --augment 0.8 --augment-survey 0.5 --gap-power 3 --init "$init" --resume "${stop[@]}" "$@" \
    >> "$out.stdout.txt" 2>&1 ||
    { echo "reproduce.sh: run $name failed, see $out.stdout.txt" >&2; exit 1; }
  if [ "$check" -gt 0 ]; then
    same_log "$name" "$check" && exit 0
    exit 1
  fi
}
# A run's log against the committed one (training/runs/NAME/log.csv), its lines up to step UPTO
# (default: all) without their time (the last column); prints what differs and returns 1 if
# anything does. One tolerance: a training line's loss (the 50-step mean, logged to 4 decimals)
# may be 1e-4 off. Since session 36 train_deep.py scales each sample's loss before the mean,
# not the mean after, which rounds the last digit differently; step 17's log shows three such
# lines with the same tensors. Every other field must be the same text.
same_log() {
  local name=$1 upto=${2:-}
  strip() { awk -F, -v n="$upto" 'NR > 1 && (n == "" || $2 <= n + 0) { NF = 7; print }' OFS=, "$1"; }
  local verdict
  # Lines are paired by their kind and step, so that a line one log has and the other has not
  # (a validation at a --stop-at of session 50) is reported alone.
  verdict=$(awk -F, '
    function off(a, b) { return a > b ? a - b : b - a }
    FNR == NR { want[$1 "," $2] = $0; order[++n] = $1 "," $2; next }
    {
      key = $1 "," $2
      if (!(key in want) || (key in seen)) { print "> " $0 > "/dev/stderr"; bad++; next }
      seen[key] = 1
      if ($0 == want[key]) { same++; next }
      split(want[key], c, ",")
      close_enough = ($1 == "train" && c[3] != "" && $3 != "")
      for (i = 4; i <= 7; i++) if (c[i] != $i) close_enough = 0
      # 1.5e-4: one unit of the 4th decimal, with room for the decimal text read as binary.
      if (close_enough && off(c[3], $3) < 1.5e-4) { rounded++; next }
      print "< " want[key] > "/dev/stderr"; print "> " $0 > "/dev/stderr"; bad++
    }
    END {
      for (i = 1; i <= n; i++) if (!(order[i] in seen)) { print "< " want[order[i]] > "/dev/stderr"; bad++ }
      printf "%d %d %d\n", same, rounded, bad
    }' <(strip "training/runs/$name/log.csv") <(strip "$work/runs/$name/log.csv"))
  set -- $verdict
  if [ "$3" -eq 0 ]; then
    local rounded=""
    [ "$2" -eq 0 ] || rounded=", $2 more with the loss mean 1e-4 off"
    echo "log $name: the committed run's${upto:+ to step $upto} ($1 lines the same$rounded)"
    return 0
  fi
  echo "log $name: differs from training/runs/$name/log.csv in $3 of its lines (above: < committed, > this run)" >&2
  return 1
}
# A stage's end: FILE COMMITTED RUN...: $work/FILE exported from the last checkpoint of the
# stage's last run with the note of COMMITTED, the committed file (so that the two can match
# byte for byte), its agreement threshold calibrated, then compared with COMMITTED; the logs of
# the stage's runs say where a reproduction parted from the committed one. The export is
# skipped where the file is there and newer than the checkpoint.
ship() {
  local file=$1 ref=$2; shift 2
  local out="$work/$file" last=${!#} logs=0
  if [ "$out" -nt "$work/runs/$last/last.pt" ]; then
    echo "export: $out is there"
  else
    $py training/export_deep.py "$work/runs/$last/last.pt" "$out.part" --note-from "$ref"
    python3 training/calibrate_sharpness.py --test agreement --count 200 --only "$out.part" > "$out.log" 2>&1 ||
      { echo "reproduce.sh: the calibration failed, see $out.log" >&2; exit 1; }
    tail -n 1 "$out.log"
    mv "$out.part" "$out"
  fi
  for name in "$@"; do same_log "$name" || logs=1; done
  if $py training/same_tensors.py "$out" "$ref" && cmp "$out" "$ref"; then
    echo "reproduced: $out is $ref byte for byte"
    [ "$logs" -eq 0 ] || echo "reproduce.sh: the same file, though a log differs (above)" >&2
  else
    echo "reproduce.sh: $out differs from $ref (above)" >&2
    exit 1
  fi
}

# Stage 2: session 31's s16 (step 17), from step 16's file.
s16_17="$work/s16_step17.tlw"
if [ "$from" -eq 16 ]; then
  run s16anchor s16 1200 31 "$work/s16_step16.tlw" --val-every 400 --anchor-w 0.5 --anchor-iterations 2
  ship deep_iclk_s16_step17.tlw "$work/s16_step17.tlw" s16anchor
  s16_17="$work/deep_iclk_s16_step17.tlw"
fi
# Stage 3: s16 (step 20), from stage 2's file.
s16=weights/deep_iclk_s16.tlw
if [ "$from" -ne 20 ]; then
  run s16tilt s16 600 33 "$s16_17" --val-every 300 --tilt-prior 3
  ship deep_iclk_s16.tlw weights/deep_iclk_s16.tlw s16tilt
  s16="$work/deep_iclk_s16.tlw"
fi
# Stage 4: s16w64 (step 24), from stage 3's file.
run s16w64 s16w64 1200 38 "$s16" --val-every 300 --tilt-prior 3 --widen
run s16w64b s16w64 1200 39 "$work/runs/s16w64/last.pt" --val-every 300 --tilt-prior 3
run s16w64c s16w64 1200 40 "$work/runs/s16w64b/last.pt" --val-every 300 --tilt-prior 3
ship deep_iclk_s16w64.tlw weights/deep_iclk_s16w64.tlw s16w64 s16w64b s16w64c
