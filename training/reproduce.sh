#!/usr/bin/env bash
# The learned tracker's three shipped weight files trained again in one command, each compared
# with the committed file, from session 23's s16 file (training/README.md, step 12's; in git as
# committed in 934536e), where step 15's two-channel run s16c2 started:
#   1. the training data (training/README.md, steps 1 and 7): NAIP's five training years and the
#      Christchurch strip, rendered by `terralign dataset` at half the camera's size, twice:
#      by session 23's terralign (built from 934536e) for step 16, whose runs were trained on
#      data rendered before 26 November's terrain changes (4679138-d8fa240) moved the rendered
#      pixels, and by this checkout's for steps 17-24;
#   2. session 28's s16 file: step 16's three runs of 600 steps (two feature channels; then
#      cross-year pairs drawn by gap^3), the first compared with the file committed in 10be774,
#      the last with the one committed in 3c0722d, tensor by tensor (the thresholds in those
#      files were calibrated by session 28's eval and are not calibrated again);
#   3. session 31's s16 file: step 17's run of 1200 steps with the anchor loss, compared with the
#      file as committed in 1ada086 (its threshold calibrated under today's defaults);
#   4. weights/deep_iclk_s16.tlw (the firmware's): step 20's run of 600 steps with the tilt
#      prior, from stage 3's file;
#   5. weights/deep_iclk_s16w64.tlw (the default): step 24's three runs of 1200 steps (stage 4's
#      file widened to s16w64, then two continuations);
#   6. weights/deep_iclk_s8w48m8.tlw (the small network, not the default): step 32's run of 2000
#      steps from stage 5's file narrowed to s8w48m8.
# Stages 3-6 end with the export under the committed file's note, the agreement threshold
# calibrated (training/calibrate_sharpness.py), and every tensor and byte compared with the
# committed file (training/same_tensors.py, cmp): the verdict, and a stage that differs stops
# the command. Each run's log is compared with its committed one (training/runs/NAME/log.csv)
# too, to say where a reproduction that differs parted from it.
#
#   bash training/reproduce.sh [--work DIR] [--from STEP] [--check STEPS]
#
# --work DIR (default /work/train): the data, the runs and the weight files; each stage is
# skipped where its result is there, and a run stopped midway resumes from its checkpoint.
# --from STEP: 15 (the default) starts with step 15's s16c2 run, from step 12's file; 16, 17 or
# 20 from the file of that step: 16 runs stages 3-6 from the file committed in 3c0722d, 17
# stages 4-6 from the file committed in 1ada086, 20 stages 5 and 6 from the committed
# weights/deep_iclk_s16.tlw (session 50's command), 24 stage 6 alone from the committed
# weights/deep_iclk_s16w64.tlw.
# --check STEPS: only the first run's first STEPS steps, whose log (training loss every 50
# steps, validation every 300, 400 or 600) is then compared with the committed one line by
# line, the times aside; a training loss mean may be 1e-4 off (step 17's log has three such,
# their rounding, the tensors the same: same_log below).
#
# Needs the release build of the README's test command (build/release), Debian's
# python3-torch and python3-matplotlib (`apt-get install python3-torch python3-matplotlib`;
# /usr/bin/python3, not a pyenv python3), ../shared/data beside the checkout and, from step 15,
# 16 or 17, the checkout's git history. On two cores: about 5 minutes of data a renderer (and
# 4 to build session 23's); about 55 minutes of training for stage 2, 50 for stage 3, 20 for
# stage 4, 2.6 hours for stage 5 (session 38: 2475, 3360 and 3441 s) and 65 minutes for stage 6
# (session 66, on an AVX2 host: 3901 s); 2-5 minutes of
# calibration a file; 7.4 GB of data. A byte-for-byte result also needs PyTorch's oneDNN to run
# the kernels it ran here (AVX-512; training/README.md). The chain before step 12's file is not
# one command: its runs (sessions 3-23, training/README.md steps 2-12) were trained by earlier
# versions of train_deep.py (four levels at first), on data of earlier renderers, each from the
# file the session before had committed.
set -euo pipefail
cd "$(dirname "$0")/.."
work=/work/train
check=0
from=15
while [ $# -gt 0 ]; do
  case "$1" in
    --work) work=${2:?--work needs a directory}; shift 2 ;;
    --check) check=${2:?--check needs a number of steps}; shift 2 ;;
    --from) from=${2:?--from needs a training step: 15, 16, 17, 20 or 24}; shift 2 ;;
    *) echo "reproduce.sh: unknown argument '$1' (--work DIR, --from STEP, --check STEPS)" >&2; exit 2 ;;
  esac
done
case "$from" in
  15|16|17|20|24) ;;
  *) echo "reproduce.sh: --from '$from' is not 15, 16, 17, 20 or 24 (training/README.md's steps)" >&2; exit 2 ;;
esac
case "$check" in
  ''|*[!0-9]*) echo "reproduce.sh: --check '$check' is not a number of steps" >&2; exit 2 ;;
esac
py=/usr/bin/python3
tl=build/release/tools/terralign/terralign
[ -x "$tl" ] || { echo "reproduce.sh: $tl is not built (the README's test command builds it)" >&2; exit 1; }
$py -c "import torch, matplotlib" 2>/dev/null ||
  { echo "reproduce.sh: $py lacks torch or matplotlib (apt-get install python3-torch python3-matplotlib)" >&2; exit 1; }
# PyTorch's convolutions (oneDNN) pick their kernels by the CPU, and their sums round by them:
# the same bytes need a host whose oneDNN runs what sessions 50-52's ran (AVX-512;
# training/README.md, "What the same bytes need").
host=$(cd training && $py -c "import train_deep, torch; torch.set_num_threads(2); print(train_deep.host_record())")
echo "host: $host"
case "$host" in
  *avx512f*) ;;
  *) echo "reproduce.sh: warning: this CPU has no AVX-512, so oneDNN runs other kernels than the host that reproduced the committed files; expect the runs to part from their logs" >&2 ;;
esac
case "$host" in
  *MAX_CPU_ISA=*|*ATEN_CPU_CAPABILITY=*) echo "reproduce.sh: warning: an ISA cap is set in the environment ($host); expect the runs to part from their logs" >&2 ;;
esac
shared=../shared/data
for f in naip_nd_2009_2020/naip/m_4709963_se_14_1_20100629.tif whu_cd_christchurch_more_samples; do
  [ -e "$shared/$f" ] || { echo "reproduce.sh: $shared/$f is missing (the shared data beside the checkout)" >&2; exit 1; }
done
# The files of steps 15, 16 and 17 from git (10be774: step 16's first run, shipped alone first;
# 1ada086 recalibrated step 17's threshold under the tilt prior that became the default then,
# its tensors unchanged).
step15=934536e:weights/deep_iclk_s16.tlw
step16a=10be774:weights/deep_iclk_s16.tlw
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
[ "$from" -gt 16 ] || committed s16_step16.tlw "$step16"
if [ "$from" -eq 15 ]; then
  committed s16_step15.tlw "$step15"
  committed s16_step16a.tlw "$step16a"
fi

# The training data of steps 1 and 7 as TERRALIGN renders them: NAIP to $work/naip_376SUFFIX,
# the Christchurch strip to $work/chch_376SUFFIX. Each set is written to DIR.part and renamed
# when whole: a stopped render is redone, never half used.
datasets() {
  local bin=$1 suffix=$2
  dataset "$bin" "$work/naip_376$suffix" --map training/naip_train_years.json --camera data/cameras/uav_752x480.json \
    --count 1500 --seed 20261122 --altitude 600:900 --tilt 10 --split-fraction 0.3 --scale 0.5
  if [ ! -f "$work/chch_map/christchurch_train.json" ]; then
    rm -rf "$work/chch_map.part"
    $py training/make_christchurch_mosaic.py "$work/chch_map.part"
    mv "$work/chch_map.part" "$work/chch_map"
  fi
  dataset "$bin" "$work/chch_376$suffix" --map "$work/chch_map/christchurch_train.json" --camera data/cameras/uav_752x480.json \
    --count 600 --seed 20261123 --altitude 45:65 --tilt 10 --split-fraction 0.3 --scale 0.5
}
dataset() {  # TERRALIGN OUT ARGS...
  local bin=$1 out=$2; shift 2
  if [ -f "$out/index.csv" ]; then echo "data: $out is there"; return; fi
  rm -rf "$out.part"
  "$bin" dataset "$@" --out "$out.part" > "$out.log" 2>&1 || { echo "reproduce.sh: terralign dataset failed, see $out.log" >&2; exit 1; }
  mv "$out.part" "$out"
  tail -n 1 "$out.log"
}
# terralign built from COMMIT's tree in $work/terralign-COMMIT, its path in $built.
build_at() {
  local commit=$1 dir="$work/terralign-$1"
  built="$dir/build/tools/terralign/terralign"
  [ -x "$built" ] && return
  git cat-file -e "$commit^{commit}" 2>/dev/null ||
    { echo "reproduce.sh: commit $commit is not in this checkout's git history (clone the repository, or --from 16)" >&2; exit 1; }
  echo "build: $commit's terralign in $dir (log: $dir.log)"
  rm -rf "$dir" && mkdir -p "$dir"
  git archive "$commit" | tar -x -C "$dir"
  { cmake -S "$dir" -B "$dir/build" -DCMAKE_BUILD_TYPE=Release && cmake --build "$dir/build" -j2 --target terralign_cli; } \
    > "$dir.log" 2>&1 || { echo "reproduce.sh: building $commit failed, see $dir.log" >&2; exit 1; }
}
if [ "$from" -eq 15 ]; then
  build_at 934536e
  datasets "$built" _s23
fi
# (A --check from step 15 runs only on session 23's renders.)
[ "$from" -eq 15 ] && [ "$check" -gt 0 ] || datasets "$tl" ""

# A run of training/README.md's steps 16, 17, 20 and 24 on the data named by $data (the suffix
# of $work/naip_376 and chch_376): NAME SIZE STEPS SEED INIT [ARGS: the step's own flags].
# Resumes a stopped run; skipped where its last checkpoint is at STEPS.
# Under --check: to step STEPS of --check, then its log compared with the committed one, and
# the command ends.
run() {
  local name=$1 size=$2 steps=$3 seed=$4 init=$5; shift 5
  local out="$work/runs/$name" stop=()
  # The committed run's host, where it was recorded (since session 52): another CPU runs other
  # oneDNN kernels, and the run parts from its log (session 90: step 32's run, trained on an
  # AMD EPYC with AVX2, parted at step 50 on an Intel Xeon with AVX-512, capped at AVX2 too,
  # on data whose every image was the committed run's).
  local record="training/runs/$name/host.txt" then_host
  then_host=$(sed -n 's/^started: //p' "$record" 2>/dev/null | head -n 1)
  if [ -n "$then_host" ] && [ "${then_host#*; }" != "${host#*; }" ]; then
    echo "reproduce.sh: warning: run $name was trained on another host ($then_host; $record); expect it to part from its log" >&2
  fi
  [ "$check" -gt 0 ] && stop=(--stop-at "$check")
  # A check resumed from a checkpoint already there would compare an old log with itself.
  if [ "$check" -gt 0 ] && [ -e "$out/last.pt" ]; then
    echo "reproduce.sh: --check needs a fresh run, but $out/last.pt is there (give --work a new directory)" >&2
    exit 1
  fi
  if [ "$check" -eq 0 ] && [ -f "$out/last.pt" ] &&
     [ "$($py -c "import sys, torch; print(torch.load(sys.argv[1])['step'])" "$out/last.pt")" = "$steps" ]; then
    echo "run $name: done"; return
  fi
  echo "run $name: $out.stdout.txt"
  $py training/train_deep.py --data "$work/naip_376$data" --extra "$work/chch_376$data" --extra-p 0.35 --out "$out" \
    --size "$size" --channels 2 --steps "$steps" --batch 4 --iterations 5 --lr 3e-4 --seed "$seed" \
    --val-count 64 --augment 0.8 --augment-survey 0.5 --init "$init" --resume "${stop[@]}" "$@" \
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
    [ "$2" -eq 0 ] || rounded="; with the loss mean 1e-4 off: $2"
    echo "log $name: the committed run's${upto:+ to step $upto} (lines the same: $1$rounded)"
    return 0
  fi
  echo "log $name: differs from training/runs/$name/log.csv in $3 of its lines (above: < committed, > this run)" >&2
  return 1
}
# A stage's end: [--tensors] FILE COMMITTED RUN...: $work/FILE exported from the last
# checkpoint of the stage's last run with the note of COMMITTED, the committed file (so that the
# two can match byte for byte), its agreement threshold calibrated (and the one with an
# attitude reference, where COMMITTED has it: the default file since session 59), then compared with
# COMMITTED (with the agreement test's start COMMITTED carries, `# agree-px`: none in the
# shipped files; session 54 gave step 24's 1 px, session 55 took it back); the logs of the
# stage's runs say where a reproduction parted from the committed one. The export is skipped
# where the file is there and newer than the checkpoint. With --tensors (step 16, whose
# committed thresholds were calibrated by session 28's eval, under other defaults) the
# threshold is not calibrated and the verdict is the tensors alone: the next step reads only
# those.
ship() {
  local tensors=0
  [ "$1" != --tensors ] || { tensors=1; shift; }
  local file=$1 ref=$2; shift 2
  local out="$work/$file" last=${!#} logs=0
  if [ "$out" -nt "$work/runs/$last/last.pt" ]; then
    echo "export: $out is there"
  else
    $py training/export_deep.py "$work/runs/$last/last.pt" "$out.part" --note-from "$ref"
    if [ "$tensors" -eq 0 ]; then
      local start
      start=$(grep -a -m 1 '^# agree-px ' "$ref" | cut -d ' ' -f 3)
      python3 training/calibrate_sharpness.py --test agreement ${start:+--agree-px "$start"} --count 200 --only \
        "$out.part" > "$out.log" 2>&1 ||
        { echo "reproduce.sh: the calibration failed, see $out.log" >&2; exit 1; }
      tail -n 1 "$out.log"
      # The threshold with an attitude reference, where COMMITTED carries one (session 59).
      if grep -a -q '^# max-disagreement-px-attitude ' "$ref"; then
        python3 training/calibrate_sharpness.py --test agreement-attitude --pair 2009,2020 --count 1000 \
          "$out.part" > "$out.attitude.log" 2>&1 ||
          { echo "reproduce.sh: the calibration failed, see $out.attitude.log" >&2; exit 1; }
        tail -n 1 "$out.attitude.log"
      fi
      # With an altimeter too, where COMMITTED carries that line (session 76).
      if grep -a -q '^# max-disagreement-px-attitude-altimeter ' "$ref"; then
        python3 training/calibrate_sharpness.py --test agreement-attitude-altimeter --pair 2009,2020 --count 1000 \
          "$out.part" > "$out.altimeter.log" 2>&1 ||
          { echo "reproduce.sh: the calibration failed, see $out.altimeter.log" >&2; exit 1; }
        tail -n 1 "$out.altimeter.log"
      fi
    fi
    mv "$out.part" "$out"
  fi
  for name in "$@"; do same_log "$name" || logs=1; done
  $py training/same_tensors.py "$out" "$ref" && { [ "$tensors" -eq 1 ] || cmp "$out" "$ref"; } ||
    { echo "reproduce.sh: $out differs from $ref (above)" >&2; exit 1; }
  if [ "$tensors" -eq 1 ]; then
    echo "reproduced: $out holds $ref's tensors, bit for bit"
  else
    echo "reproduced: $out is $ref byte for byte"
  fi
  [ "$logs" -eq 0 ] || echo "reproduce.sh: the same result, though a log differs (above)" >&2
}

# Stage 2: session 28's s16 (step 16), from session 23's file, on session 23's renders.
s16_16="$work/s16_step16.tlw"
if [ "$from" -eq 15 ]; then
  data=_s23
  run s16c2 s16 600 27 "$work/s16_step15.tlw" --val-every 600 --gap-power 1.5
  ship --tensors deep_iclk_s16_step16a.tlw "$work/s16_step16a.tlw" s16c2
  run s16c2g3 s16 600 29 "$work/runs/s16c2/last.pt" --val-every 600 --gap-power 3
  run s16c2g3b s16 600 30 "$work/runs/s16c2g3/last.pt" --val-every 600 --gap-power 3
  ship --tensors deep_iclk_s16_step16.tlw "$work/s16_step16.tlw" s16c2g3 s16c2g3b
  s16_16="$work/deep_iclk_s16_step16.tlw"
fi
# Steps 17-24 on this checkout's renders.
data=""
# Stage 3: session 31's s16 (step 17), from step 16's file.
s16_17="$work/s16_step17.tlw"
if [ "$from" -le 16 ]; then
  run s16anchor s16 1200 31 "$s16_16" --val-every 400 --gap-power 3 --anchor-w 0.5 --anchor-iterations 2
  ship deep_iclk_s16_step17.tlw "$work/s16_step17.tlw" s16anchor
  s16_17="$work/deep_iclk_s16_step17.tlw"
fi
# Stage 4: s16 (step 20), from stage 3's file.
s16=weights/deep_iclk_s16.tlw
if [ "$from" -lt 20 ]; then
  run s16tilt s16 600 33 "$s16_17" --val-every 300 --gap-power 3 --tilt-prior 3
  ship deep_iclk_s16.tlw weights/deep_iclk_s16.tlw s16tilt
  s16="$work/deep_iclk_s16.tlw"
fi
# Stage 5: s16w64 (step 24), from stage 4's file.
s16w64=weights/deep_iclk_s16w64.tlw
if [ "$from" -lt 24 ]; then
  run s16w64 s16w64 1200 38 "$s16" --val-every 300 --gap-power 3 --tilt-prior 3 --widen
  run s16w64b s16w64 1200 39 "$work/runs/s16w64/last.pt" --val-every 300 --gap-power 3 --tilt-prior 3
  run s16w64c s16w64 1200 40 "$work/runs/s16w64b/last.pt" --val-every 300 --gap-power 3 --tilt-prior 3
  ship deep_iclk_s16w64.tlw weights/deep_iclk_s16w64.tlw s16w64 s16w64b s16w64c
  s16w64="$work/deep_iclk_s16w64.tlw"
fi
# Stage 6: s8w48m8 (step 32), from stage 5's file narrowed.
run s8w48m8 s8w48m8 2000 41 "$s16w64" --val-every 500 --gap-power 3 --tilt-prior 3 --narrow
ship deep_iclk_s8w48m8.tlw weights/deep_iclk_s8w48m8.tlw s8w48m8
