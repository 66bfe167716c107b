#!/usr/bin/env python3
"""Calibrates one of the learned tracker's converged tests for one weight file and writes
its threshold into it (read by src/iclk/deep_aligner.cpp):

- `--test sharpness` (the default): `# min-sharpness X`. The tracker reports an answer as
  failed when its feature agreement 2 px away is within a factor X of the final one
  (iclk::TrackResult::sharpness). Rounded down to 0.005.
- `--test agreement`: `# max-disagreement-px X`. The tracker reports an answer as failed when
  a second start D working px away in u and v settles more than X px from it
  (iclk::TrackResult::disagreement_px). Rounded up to 0.05. D is the file's `# agree-px`, 2
  where it has none; `--agree-px D` calibrates with that start and writes its line with the
  threshold, so that the threshold holds for the start the tracker will use (session 54 gave
  the default file 1 px, session 55 took it back: README, "The agreement test's start").
- `--test agreement-attitude`: `# max-disagreement-px-attitude X`, the agreement threshold
  where the tilt prior is an attitude reference's (at most 1 degree:
  iclk::DeepAligner::kAttitudeTiltPriorDeg). Two runs of the pair, without and with an IMU's
  tilt (`--imu-tilt 0.5 --tilt-prior 0.5`): the share of right answers among those the file's
  `# max-disagreement-px` passes without the IMU is the trust to keep; from that threshold,
  in steps of 0.05 px, the widest whose passed answers with the IMU are right at least as
  often (session 59: 2009 -> 2020, 1000 poses, 98.9 % -> 1.35 px).
- `--test agreement-attitude-altimeter`: `# max-disagreement-px-attitude-altimeter X`, the
  same with an altimeter too, where the altitude prior is at most
  iclk::DeepAligner::kAltimeterPriorM: the second run adds `--altimeter 2` (session 76:
  1.60 px).

The first two keep `--keep` (97 %) of the right converged answers (2-D EPE < 5 px) of an
adjacent-year pair on calibration poses (seed 11; the README's tables use seed 7). Runs
`terralign eval ... --min-sharpness -1 --max-disagreement -1 --json` (both tests off, the
other options eval's defaults: since session 33 the 3-degree tilt prior);
Python's standard library only. `--area MINX,MINY,MAXX,MAXY` takes the poses from that part of
the map alone, as `eval --area` does: the held-out strip (0,5208159.9,1e9,1e9) for a file
trained on the rest of the tile in the map's own years (session 53).

  training/calibrate_sharpness.py weights/deep_iclk_s16.tlw
  training/calibrate_sharpness.py --test agreement --count 200 --only weights/deep_iclk_s16.tlw
  training/calibrate_sharpness.py --test agreement --count 200 --only weights/deep_iclk_s16w64.tlw
  training/calibrate_sharpness.py --test agreement --agree-px 1 --count 200 --only other.tlw
  training/calibrate_sharpness.py --test agreement-attitude --pair 2009,2020 --count 1000 weights/deep_iclk_s16w64.tlw
  training/calibrate_sharpness.py --test agreement-attitude-altimeter --pair 2009,2020 --count 1000 weights/deep_iclk_s16w64.tlw
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tlw  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def set_line(weights, key, text, drop=None):
    """Writes `# key text` into the file's header after `# levels` (in place of any `# key`
    line), the tensors unchanged; `drop`: another key whose line goes."""
    arch, _ = tlw.architecture(weights)
    lines = [l for l in arch.split("\n") if not l.startswith(f"# {key} ") and not (drop and l.startswith(f"# {drop} "))]
    at = next(i for i, l in enumerate(lines) if l.startswith("# levels ")) + 1
    lines.insert(at, f"# {key} {text}")
    tlw.replace_architecture(weights, "\n".join(lines))


def run_eval(a, ref, query, extra):
    """The learned tracker's answers on the calibration poses, both tests off (their measures kept)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "eval.json")
        subprocess.run([a.terralign, "eval", "--map", a.map, "--camera", a.camera, "--ref-layer", ref,
                        "--query-layer", query, "--count", str(a.count), "--seed", str(a.seed), "--altitude",
                        "700:900", "--tilt", "10", "--methods", "nn:20", "--weights", a.weights,
                        "--min-sharpness", "-1", "--max-disagreement", "-1", "--json", out]
                       + extra + (["--area", a.area] if a.area else []), check=True, stdout=subprocess.DEVNULL)
        return json.load(open(out))["methods"]["nn:20"]["samples"]


def passed(samples, threshold):
    """(right, wrong) among the converged answers whose second start settled within threshold px."""
    kept = [s for s in samples if s["converged"] and s.get("disagreement_px", math.inf) <= threshold + 1e-9]
    right = sum(s["epe_px"] < 5 for s in kept)
    return right, len(kept) - right


# The sensors of each threshold that keeps the plain one's trust: the weight file's line, what
# the second run adds to the eval, and what the messages call them.
SENSORS = {
    "agreement-attitude": ("max-disagreement-px-attitude", ["--imu-tilt", "0.5", "--tilt-prior", "0.5"], "the IMU"),
    "agreement-attitude-altimeter": ("max-disagreement-px-attitude-altimeter",
                                     ["--imu-tilt", "0.5", "--tilt-prior", "0.5", "--altimeter", "2"],
                                     "the IMU and the altimeter"),
}


def with_sensors(a, ref, query):
    key, extra, sensors = SENSORS[a.test]
    arch, _ = tlw.architecture(a.weights)
    line = next((l for l in arch.split("\n") if l.startswith("# max-disagreement-px ")), None)
    if line is None:
        sys.exit(f"{a.weights}: no '# max-disagreement-px' line: calibrate the plain threshold first (--test agreement)")
    plain = float(line.split()[2])
    without = run_eval(a, ref, query, [])
    with_imu = run_eval(a, ref, query, extra)
    right, wrong = passed(without, plain)
    if right + wrong < 20:
        sys.exit(f"{a.weights}: the plain threshold passes only {right + wrong} answers of {ref} -> {query}: too few")
    trust = right / (right + wrong)

    def share(t):  # of the answers t passes with the sensors, the right ones
        r, w = passed(with_imu, t)
        return r / (r + w) if r + w else 1.0

    steps = round(plain / 0.05)  # the threshold in steps of 0.05 px, from the plain one
    if share(steps * 0.05) >= trust:
        while steps < 2000 and share((steps + 1) * 0.05) >= trust:
            steps += 1
    else:
        while steps > 1 and share(steps * 0.05) < trust:
            steps -= 1
    threshold = steps * 0.05
    r, w = passed(with_imu, threshold)
    r0, w0 = passed(with_imu, plain)
    set_line(a.weights, key, f"{threshold:.2f}")
    print(f"{a.weights}: {key} {threshold:.2f} ({ref} -> {query}, {a.count} poses, seed "
          f"{a.seed}): without {sensors} {plain:.2f} px passes {right} right and {wrong} wrong answers "
          f"({100 * trust:.1f} % right); with them {threshold:.2f} px passes {r} right and {w} wrong "
          f"({plain:.2f} px: {r0} and {w0})")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("weights")
    p.add_argument("--terralign", default=os.path.join(ROOT, "build/release/tools/terralign/terralign"))
    p.add_argument("--map", default=os.path.join(ROOT, "data/naip_west/map.json"))
    p.add_argument("--camera", default=os.path.join(ROOT, "data/cameras/uav_752x480.json"))
    p.add_argument("--pair", default="2016,2017", help="reference and query layers")
    p.add_argument("--count", type=int, default=100)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--keep", type=float, default=0.97, help="share of right converged answers to keep")
    p.add_argument("--area", help="MINX,MINY,MAXX,MAXY: the calibration poses from this part of the map (eval --area)")
    p.add_argument("--test", choices=("sharpness", "agreement") + tuple(SENSORS), default="sharpness")
    p.add_argument("--only", action="store_true",
                   help="remove the other test's threshold from the weights (its test then off by default)")
    p.add_argument("--agree-px", type=float,
                   help="the agreement test's start (working px in u and v): calibrated with, written as '# agree-px'")
    a = p.parse_args()
    ref, query = a.pair.split(",")
    if a.test in SENSORS:
        if a.agree_px is not None or a.only:
            sys.exit(f"--agree-px and --only: not with --test {a.test} (it calibrates the file's own start)")
        return with_sensors(a, ref, query)
    if a.agree_px is not None:
        if a.test != "agreement" or not 0 < a.agree_px <= 10:
            sys.exit(f"--agree-px {a.agree_px}: only with --test agreement, and in (0, 10] pixels")
    # The new start reaches the eval as its option (eval --agree-px): the file itself changes
    # only once its start and threshold are both known, so a calibration that fails leaves it
    # as it was.
    samples = run_eval(a, ref, query, ["--agree-px", f"{a.agree_px:g}"] if a.agree_px is not None else [])
    # Each test as "higher is more likely right": sharpness, and minus the disagreement (a
    # second start that failed has none in the JSON: infinitely far).
    sharp = a.test == "sharpness"
    key, line_key = ("sharpness", "min-sharpness") if sharp else ("disagreement_px", "max-disagreement-px")
    score = (lambda s: s["sharpness"]) if sharp else (lambda s: -s.get("disagreement_px", math.inf))
    right = sorted(score(s) for s in samples if s["converged"] and s["epe_px"] < 5)
    wrong = [score(s) for s in samples if s["converged"] and s["epe_px"] >= 5]
    if len(right) < 20:
        sys.exit(f"{a.weights}: only {len(right)} right converged answers on {ref} -> {query}: too few to calibrate")
    q = right[int(math.floor((1 - a.keep) * (len(right) - 1)))]
    if not math.isfinite(q):
        sys.exit(f"{a.weights}: over {100 * (1 - a.keep):.0f} % of the right answers' second starts failed: no threshold")
    if sharp:
        threshold = math.floor(q / 0.005) * 0.005
        text = f"{threshold:.3f}"
    else:
        threshold = -math.ceil(-q / 0.05 - 1e-9) * 0.05
        text = f"{-threshold:.2f}"
    kept = sum(v >= threshold for v in right)
    rejected = sum(v < threshold for v in wrong)
    if a.agree_px is not None:
        set_line(a.weights, "agree-px", f"{a.agree_px:g}")
    set_line(a.weights, line_key, text, drop=("max-disagreement-px" if sharp else "min-sharpness") if a.only else None)
    where = f", area {a.area}" if a.area else ""
    print(f"{a.weights}: {line_key} {text} ({key}; {ref} -> {query}{where}, {a.count} poses, seed {a.seed}): keeps "
          f"{kept} of {len(right)} right converged answers, fails {rejected} of {len(wrong)} wrong ones")


if __name__ == "__main__":
    main()
