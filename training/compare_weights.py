#!/usr/bin/env python3
"""Compares learned-tracker weight files on the README's evaluation rows, the way sessions
34-38 chose what to ship: `terralign eval` on the same poses for every file, within 5 px and
the median 3-D EPE per row, the rows' sums (NAIP and Christchurch apart), and pose by pose
how many answers each file gets right that the first file does not (a paired count: z =
(b - c) / sqrt(b + c), about 2 for a difference one seed's 200 poses would rarely show by
chance).

  training/compare_weights.py weights/deep_iclk_s16.tlw NEW.tlw [--seeds 11,7,13]
      [--rows 2016-2017,2009-2020,strip,chch121] [--count 200] [--with-test] [--json-dir DIR [--reuse]]
      [-- EXTRA EVAL OPTIONS, e.g. --imu-tilt 0.5 --tilt-prior 0.5]

The rows: NAIP 2016 -> 2017, 2009 -> 2020 and the held-out strip (2012 -> 2020 north of the
training ground) at 700-900 m, tilt 10 degrees; Christchurch 000121 2012 -> 2016 at 100-140 m,
tilt 5 (the README's "Today's numbers"). On request, the strip under other pairs of years:
strip-2009-2020, strip-2009-2016, strip-2009-2017, strip-2016-2020, strip-2016-2017. Every
answer is counted (`--max-disagreement -1`, as the paper counts) unless --with-test, which
keeps each file's own agreement threshold and counts a failed answer at its prior. Python's
standard library and the built `terralign`.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NAIP = ["--map", "data/naip_west/map.json", "--altitude", "700:900", "--tilt", "10"]
STRIP = ["--area", "0,5208159.9,1e9,1e9"]  # the held-out strip: north of the training ground
ROWS = {
    "2016-2017": NAIP + ["--ref-layer", "2016", "--query-layer", "2017"],
    "2009-2020": NAIP + ["--ref-layer", "2009", "--query-layer", "2020"],
    "strip": NAIP + ["--ref-layer", "2012", "--query-layer", "2020"] + STRIP,
    "chch121": ["--map", "data/christchurch/000121.json", "--altitude", "100:140", "--tilt", "5",
                "--ref-layer", "2012", "--query-layer", "2016"],
}
DEFAULT_ROWS = list(ROWS)
# The held-out strip under other pairs of the sample's years ("strip-A-B"; session 53): the ground
# no training map holds, for a file trained on these years elsewhere on the tile.
for _a, _b in (("2009", "2020"), ("2009", "2016"), ("2009", "2017"), ("2016", "2020"), ("2016", "2017")):
    ROWS[f"strip-{_a}-{_b}"] = NAIP + ["--ref-layer", _a, "--query-layer", _b] + STRIP


def run_eval(terralign, weights, row, seed, count, with_test, extra, out, reuse):
    if reuse and os.path.isfile(out):
        return read(out)
    cmd = [terralign, "eval", "--camera", "data/cameras/uav_752x480.json", "--count", str(count), "--seed",
           str(seed), "--methods", "nn:20", "--threads", "2", "--weights", weights, "--json", out] + ROWS[row]
    if not with_test:
        cmd += ["--max-disagreement", "-1"]
    subprocess.run(cmd + extra, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return read(out)


def read(out):
    samples = json.load(open(out))["methods"]["nn:20"]["samples"]
    # An answer reported failed stands at its prior (eval's JSON holds the prior's error then).
    return [s["epe_px"] < 5 for s in samples], sorted(s["epe_m"] for s in samples)


def median(xs):
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def main():
    argv = sys.argv[1:]
    extra = []
    if "--" in argv:
        k = argv.index("--")
        argv, extra = argv[:k], argv[k + 1:]
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("weights", nargs="+")
    p.add_argument("--terralign", default=os.path.join(ROOT, "build/release/tools/terralign/terralign"))
    p.add_argument("--seeds", default="11,7,13")
    p.add_argument("--rows", default=",".join(DEFAULT_ROWS))
    p.add_argument("--count", type=int, default=200)
    p.add_argument("--with-test", action="store_true", help="keep each file's agreement test (eval's default)")
    p.add_argument("--json-dir", help="keep eval's JSON files here (default: a temporary folder)")
    p.add_argument("--reuse", action="store_true",
                   help="take a row from --json-dir where an earlier run left it (the same file name, count, "
                        "test and options; not checked: clear the folder after changing the build or options)")
    a = p.parse_args(argv)
    if a.reuse and not a.json_dir:
        sys.exit("compare_weights: --reuse needs --json-dir")
    seeds = [int(s) for s in a.seeds.split(",")]
    rows = a.rows.split(",")
    for r in rows:
        if r not in ROWS:
            sys.exit(f"compare_weights: row '{r}' is not one of {', '.join(ROWS)}")
    for w in a.weights:
        if not os.path.isfile(w):
            sys.exit(f"compare_weights: weight file '{w}' does not exist")
    weights = [os.path.abspath(w) for w in a.weights]
    if len({os.path.basename(w) for w in weights}) < len(weights):
        sys.exit("compare_weights: two weight files of one name (their rows' JSON files would collide)")
    tmp = tempfile.TemporaryDirectory()
    folder = a.json_dir or tmp.name
    os.makedirs(folder, exist_ok=True)
    right, epe = {}, {}
    for r in rows:
        for s in seeds:
            for i, w in enumerate(weights):
                out = os.path.join(folder, f"{r}_s{s}_{os.path.basename(w)}.json")
                right[r, s, i], epe[r, s, i] = run_eval(a.terralign, w, r, s, a.count, a.with_test, extra, out,
                                                     a.reuse)
                print(f"{r} seed {s} {os.path.basename(w)}: {100.0 * sum(right[r, s, i]) / a.count:.1f} % within 5 px",
                      file=sys.stderr, flush=True)
    names = [os.path.basename(w) for w in a.weights]
    print(f"within 5 px, % ({'the agreement test on' if a.with_test else 'every answer counted'}; "
          f"median 3-D EPE m in brackets), seeds {a.seeds}, {a.count} poses each" + (f", {' '.join(extra)}" if extra else ""))
    print()
    print("| row | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for r in rows:
        cells = []
        for i in range(len(weights)):
            cells.append(" / ".join(f"{100.0 * sum(right[r, s, i]) / a.count:.1f} ({median(epe[r, s, i]):.2f})"
                                    for s in seeds))
        print(f"| {r} | " + " | ".join(cells) + " |")
    sums = []
    for i in range(len(weights)):
        naip = sum(100.0 * sum(right[r, s, i]) / a.count for r in rows for s in seeds if r != "chch121")
        chch = sum(100.0 * sum(right[r, s, i]) / a.count for r in rows for s in seeds if r == "chch121")
        sums.append(f"{naip + chch:.1f} ({naip:.1f}, {chch:.1f})")
    print("| sum (NAIP, Christchurch) | " + " | ".join(sums) + " |")
    for i in range(1, len(weights)):
        print()
        print(f"{names[i]} against {names[0]}, pose by pose (right by this file only / by the first only, z):")
        for group, keep in (("NAIP", lambda r: r != "chch121"), ("Christchurch", lambda r: r == "chch121")):
            b = c = 0
            for r in rows:
                for s in seeds:
                    if keep(r):
                        b += sum(1 for x, y in zip(right[r, s, i], right[r, s, 0]) if x and not y)
                        c += sum(1 for x, y in zip(right[r, s, i], right[r, s, 0]) if y and not x)
            if b + c:
                print(f"  {group}: {b} / {c}, z = {(b - c) / math.sqrt(b + c):.1f}")


if __name__ == "__main__":
    main()
