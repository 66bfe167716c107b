#!/usr/bin/env python3
"""The README's tracking table: render the synthetic flights once, track each on its map and
print position RMSE / max, angle RMSE, converged share, refused answers and NEES per row.

  python3 scripts/track_flights.py --out /tmp/flights [--method nn] [-- extra track options]

Flights (README "Tracking a flight"): the 40-frame lawnmower at 800 m with --noise 2 --blur 1
--exposure 0.1 --imu-tilt 0.5, rendered from 2016, 2017 and 2020, and the circle at 750 m from
2017. Rows: the same year (2016 on the 2016 map), a year (2017 on 2016), the circle (2017 on
2016), 4 years (2020 on 2016) and 11 years (2020 on 2009), each without and with the IMU's
tilt (--attitude, --tilt-prior 0.5). --altimeter: every track also holds its answers' altitude
to the flight's altimeter (rendered with --altimeter 2: the true z plus N(0, 2 m); --altimeter
DIR/altimeter.txt --altitude-prior 2). Python's standard library and the built terralign only.
"""
import argparse
import json
import math
import os
import random
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAP = os.path.join(ROOT, "data/naip_west/map.json")
CAM = os.path.join(ROOT, "data/cameras/uav_752x480.json")

FLIGHTS = {  # name: (layer, extra flight options)
    "lawn2016": ("2016", []),
    "lawn2017": ("2017", []),
    "lawn2020": ("2020", []),
    "circle2017": ("2017", ["--path", "circle", "--altitude", "750"]),
}
# --check: README's check flight instead, not used to set anything (faster, higher, tilted,
# noisier, another seed), from 2016, 2017 and 2020.
CHECK = ["--speed", "30", "--altitude", "900", "--tilt", "5", "--noise", "3", "--exposure", "0.15", "--seed", "9"]
ROWS = [  # label, flight, map layer
    ("same year", "lawn2016", "2016"),
    ("a year", "lawn2017", "2016"),
    ("a year, circle", "circle2017", "2016"),
    ("4 years", "lawn2020", "2016"),
    ("11 years", "lawn2020", "2009"),
]


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("failed (%d): %s\n%s" % (r.returncode, " ".join(cmd), r.stderr[-2000:]))


def random_flights(out, n, seed):
    """N straight 1000 m flights (40 frames at 25 m/s) inside the sample map's common extent,
    away from its edges by the footprint, as `flight` keeps its own paths."""
    rng = random.Random(seed)
    x0, x1, y0, y1 = 485902.0, 488999.0, 5205628.0, 5209245.0  # `terralign info`: covered by every layer
    flights, rows = {}, []
    for k in range(n):
        alt = rng.uniform(700, 900)
        tilt = rng.uniform(0, 10)
        margin = alt * math.hypot(752 / 651.2, 480 / 651.2) / 2 * 1.2 + alt * math.tan(math.radians(tilt)) + 10
        while True:
            h = rng.uniform(0, 2 * math.pi)
            ax, ay = rng.uniform(x0 + margin, x1 - margin), rng.uniform(y0 + margin, y1 - margin)
            bx, by = ax + 1050 * math.sin(h), ay + 1050 * math.cos(h)
            if x0 + margin < bx < x1 - margin and y0 + margin < by < y1 - margin:
                break
        path = os.path.join(out, "path%d_s%d.txt" % (k, seed))
        with open(path, "w") as f:
            f.write("%.3f %.3f\n%.3f %.3f\n" % (ax, ay, bx, by))
        extra = ["--path", path, "--altitude", "%.1f" % alt, "--tilt", "%.2f" % tilt, "--seed", str(seed * 100 + k)]
        for y in ("2016", "2017", "2020"):
            flights["r%d_s%d_%s" % (k, seed, y)] = (y, extra)
        for label, fl, layer in ROWS:
            if not fl.startswith("circle"):
                rows.append(("%s, flight %d" % (label, k), "r%d_s%d_%s" % (k, seed, fl[4:]), layer))
    return flights, rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="folder for the flights and the tracks")
    ap.add_argument("--tl", default=os.path.join(ROOT, "build/release/tools/terralign/terralign"))
    ap.add_argument("--method", default="nn", choices=["nn", "classic"])
    ap.add_argument("--tag", default="run", help="name of this set of tracks (their files)")
    ap.add_argument("--rows", default="", help="comma-separated row labels to run (default all; with --random, "
                    "a label without its flight, e.g. '11 years', runs that row of every flight)")
    ap.add_argument("extra", nargs="*", help="options passed to every track (after --)")
    ap.add_argument("--check", action="store_true", help="the check flight (README) instead of the lawnmower")
    ap.add_argument("--random", type=int, default=0, metavar="N",
                    help="N random straight 1000 m flights instead (heading, place, altitude 700-900 m, tilt 0-10 deg)")
    ap.add_argument("--seed", type=int, default=1, help="the random flights' seed")
    ap.add_argument("--altimeter", action="store_true", help="every track with the flight's altimeter (2 m)")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    flights = FLIGHTS
    rows = ROWS
    if a.check:
        flights = {"check" + y: (y, CHECK) for y in ("2016", "2017", "2020")}
        rows = [(label, "check" + fl[4:], layer) for label, fl, layer in ROWS if not fl.startswith("circle")]
    if a.random:
        flights, rows = random_flights(a.out, a.random, a.seed)
    wanted = set(a.rows.split(",")) if a.rows else None

    def runs(label):
        return not wanted or label in wanted or label.split(", flight")[0] in wanted

    needed = {flight for label, flight, _ in rows if runs(label)}  # render only what the rows track
    for name, (layer, extra) in flights.items():
        d = os.path.join(a.out, name)
        if name not in needed or os.path.exists(os.path.join(d, "altimeter.txt")):
            continue
        # The altimeter's readings come from a stream of their own: the frames and the attitude
        # readings are those of a flight rendered without them.
        opts = {"--path": "lawnmower", "--speed": "25", "--rate": "1", "--duration": "40", "--noise": "2", "--blur": "1",
                "--exposure": "0.1", "--imu-tilt": "0.5", "--altimeter": "2"}
        opts.update(dict(zip(extra[::2], extra[1::2])))
        run([a.tl, "flight", "--map", MAP, "--camera", CAM, "--layer", layer, "--out", d] +
            [x for kv in opts.items() for x in kv])
    print("| flight | IMU | converged | refused (resets) | position RMSE / max m | angle RMSE deg | NEES mean / median |")
    print("|---|---|---|---|---|---|---|")
    results = {}
    for label, flight, layer in rows:
        if not runs(label):
            continue
        d = os.path.join(a.out, flight)
        with open(os.path.join(d, "truth.txt")) as f:
            init = f.readline().split(None, 1)[1].strip()
        for imu in (False, True):
            stem = os.path.join(a.out, "%s_%s_%s%s" % (a.tag, flight, layer, "_imu" if imu else ""))
            cmd = [a.tl, "track", "--map", MAP, "--camera", CAM, "--layer", layer, "--images",
                   os.path.join(d, "list.txt"), "--init", init, "--truth", os.path.join(d, "truth.txt"),
                   "--method", a.method, "--out", stem + ".csv", "--json", stem + ".json"]
            if imu:
                cmd += ["--attitude", os.path.join(d, "attitude.txt"), "--tilt-prior", "0.5"]
            if a.altimeter:
                cmd += ["--altimeter", os.path.join(d, "altimeter.txt"), "--altitude-prior", "2"]
            run(cmd + a.extra)
            with open(stem + ".json") as f:
                j = json.load(f)
            nees = "%.1f / %.1f" % (j["nees_mean"], j["nees_median"]) if j.get("nees_mean") is not None else "-"
            results.setdefault((label.split(", flight")[0], imu), []).append(j)
            print("| %s | %s | %.1f %% | %s | %.2f / %.2f | %.3f | %s |" % (
                label, "yes" if imu else "no", 100 * j["converged_fraction"], "%s (%s)" % (j.get("refused", "-"), j.get("resets", "-")),
                j["position_rmse_m"], j["position_max_m"], j["angle_rmse_deg"], nees), flush=True)

    if a.random:
        # Over the random flights: the median and mean RMSE, flights lost (RMSE over 50 m),
        # the share of frames converged and the mean of the flights' mean NEES.
        print("\n| flights | IMU | position RMSE median / mean m | lost (RMSE > 50 m) | converged | NEES |")
        print("|---|---|---|---|---|---|")
        for (label, imu), js in results.items():
            r = sorted(j["position_rmse_m"] for j in js)
            nees = [j["nees_mean"] for j in js if j.get("nees_mean") is not None]
            print("| %s (%d) | %s | %.2f / %.2f | %d | %.1f %% | %s |" % (
                label, len(js), "yes" if imu else "no", r[len(r) // 2], sum(r) / len(r), sum(x > 50 for x in r),
                100 * sum(j["converged_fraction"] for j in js) / len(js),
                "%.1f" % (sum(nees) / len(nees)) if nees else "-"))


if __name__ == "__main__":
    main()
