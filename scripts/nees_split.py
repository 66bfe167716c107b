#!/usr/bin/python3
"""What a method's NEES is made of, from `terralign eval --json` files.

Each converged answer's JSON holds its covariance P (6x6 over [rotation about the world axes,
rad; camera centre, m]), its world-axis rotation error and its position error. Its NEES is
e^T P^-1 e over all six (6 where P is honest, median 5.35); this prints that and the marginal
NEES of the blocks (rotation 3, its tilt 2 and yaw 1, position 3, horizontal 2, height 1;
chi-square medians 2.37, 1.39, 0.45, 2.37, 1.39, 0.45 where honest), medians over the converged
answers, and the right answers' (within 5 px) median.
Needs numpy (Debian's python3-numpy).
  /usr/bin/python3 scripts/nees_split.py F.json [G.json ...] [--method nn:20]
"""
import argparse
import json
import sys

import numpy as np


def marginal(e, P, idx):
    i = np.array(idx)
    return float(e[i] @ np.linalg.solve(P[np.ix_(i, i)], e[i]))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("files", nargs="+")
    p.add_argument("--method", default="nn:20")
    o = p.parse_args()
    blocks = [("all", range(6)), ("rotation", range(3)), ("tilt", [0, 1]), ("yaw", [2]),
              ("position", range(3, 6)), ("horizontal", [3, 4]), ("height", [5])]
    for f in o.files:
        try:
            m = json.load(open(f))["methods"][o.method]
        except (OSError, ValueError, KeyError) as err:
            sys.exit(f"nees_split: {f}: {err!r} (an eval --json file with method {o.method}?)")
        rows, right = [], []
        for s in m["samples"]:
            if "covariance" not in s:
                continue
            P = np.array(s["covariance"])
            e = np.r_[s["rotation_error_rad"], -np.array(s["position_error_m"])]  # truth - estimate
            rows.append([marginal(e, P, list(b)) for _, b in blocks])
            if s["epe_px"] < 5:
                right.append(rows[-1][0])
        if not rows:
            print(f"{f}: {o.method} has no converged answer with a covariance")
            continue
        R = np.array(rows)
        med = ", ".join(f"{name} {np.median(R[:, k]):.2f}" for k, (name, _) in enumerate(blocks))
        print(f"{f}: {len(R)} converged, NEES mean {R[:, 0].mean():.1f}; medians: {med}; "
              f"right ones ({len(right)}) {np.median(right) if right else float('nan'):.2f}")


if __name__ == "__main__":
    main()
