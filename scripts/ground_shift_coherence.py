#!/usr/bin/python3
"""Whose are a tracker's misses, the maps' or the tracker's? Reads `terralign eval --json`
and compares the ground shifts (ground_shift_m: the mean displacement of the seen ground,
estimate - truth, map axes) of poses by the distance between their true camera centres.

Two years' orthophotos that disagree locally move every footprint over that ground alike, so
the map's part of a miss is shared by poses a few hundred metres apart (their footprints,
about 900 x 600 m at 800 m, mostly overlap), whatever their heading, height and tilt; a
tracker's own error is not. Prints, per distance band, the median length of the difference
of two poses' shifts and the mean cosine between them, then how much of the shifts a
smooth field explains (each pose's shift predicted from the others', Gaussian weights of
radius R, leave-one-out). Poses whose 2-D EPE is at least --max-px (gross misses) are left out.
Needs numpy (Debian's python3-numpy).
  /usr/bin/python3 scripts/ground_shift_coherence.py EVAL.json [--method nn:20] [--max-px 15]
"""
import argparse
import json
import sys

import numpy as np


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("json")
    p.add_argument("--method", default="nn:20")
    p.add_argument("--max-px", type=float, default=15.0)
    a = p.parse_args()
    try:
        with open(a.json) as f:
            d = json.load(f)
    except (OSError, ValueError) as e:
        sys.exit(f"ground_shift_coherence: {a.json}: {e}")
    m = d.get("methods", {}).get(a.method)
    if m is None:
        sys.exit(f"ground_shift_coherence: {a.json} has no method '{a.method}' (it has {', '.join(d.get('methods', {}))})")
    S = [s for s in m["samples"] if "ground_shift_m" in s and "truth_position_m" in s and s["epe_px"] < a.max_px]
    if len(S) < 3:
        sys.exit(f"ground_shift_coherence: {len(S)} poses under {a.max_px} px with a ground shift; too few "
                 "(an eval JSON from before session 26 has no ground_shift_m)")
    P = np.array([s["truth_position_m"][:2] for s in S])
    G = np.array([s["ground_shift_m"][:2] for s in S])
    print(f"{a.method}: {len(S)} of {len(m['samples'])} poses under {a.max_px} px; horizontal ground shift "
          f"mean ({G[:, 0].mean():.2f}, {G[:, 1].mean():.2f}) m east, north; RMS {np.sqrt((G ** 2).sum(1).mean()):.2f} m")
    D = np.hypot(P[:, None, 0] - P[None, :, 0], P[:, None, 1] - P[None, :, 1])
    upper = np.triu(np.ones_like(D, dtype=bool), 1)
    for lo, hi in ((0, 100), (100, 200), (200, 400), (400, 800), (800, 1e9)):
        i, j = np.where(upper & (D >= lo) & (D < hi))
        if len(i) == 0:
            continue
        diff = np.linalg.norm(G[i] - G[j], axis=1)
        cos = (G[i] * G[j]).sum(1) / (np.linalg.norm(G[i], axis=1) * np.linalg.norm(G[j], axis=1) + 1e-12)
        band = f"{lo:.0f}-{hi:.0f} m" if hi < 1e9 else f">= {lo:.0f} m"
        print(f"  centres {band:>10}: {len(i):6d} pairs, median |shift_i - shift_j| {np.median(diff):.2f} m, "
              f"mean cos {cos.mean():.2f}")
    spread = np.sqrt(((G - G.mean(0)) ** 2).sum(1).mean())
    for R in (100, 200, 400):
        W = np.exp(-(D / R) ** 2)
        np.fill_diagonal(W, 0)
        pred = (W @ G) / np.maximum(W.sum(1, keepdims=True), 1e-300)
        res = np.sqrt(((G - pred) ** 2).sum(1).mean())
        print(f"  smooth field of radius {R} m, leave-one-out: RMS left {res:.2f} m of {spread:.2f} m about the mean")


if __name__ == "__main__":
    main()
