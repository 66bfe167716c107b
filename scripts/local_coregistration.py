#!/usr/bin/python3
"""How far two co-registered images of one ground (two years' orthophotos on one grid, as
Christchurch's tiles are) disagree, as a whole and window by window.

Each window of both images is phase-correlated (scripts/phase_correlation.py); a window whose
peak is under --min-q times the correlation surface's standard deviation (q: 4-6 for unrelated
content, rising slowly with the window) has no reliable shift and is left out. Prints the whole
image's shift, then per window size the share of windows with a reliable shift and the
distribution of their shifts' lengths in metres. A tracker cannot be held to an
answer closer than what the maps agree on over the ground it sees: the Christchurch tile's
local shifts (roofs leaning differently in the two surveys) are the size of its 5 px line.
Needs numpy and PIL (Debian's python3-numpy, python3-pil).
  /usr/bin/python3 scripts/local_coregistration.py A.png B.png [--pixel-m 0.2] [--windows 64,128]
The RMS per axis over windows about a view's size is what data/christchurch's manifests state
as the two layers' registration_sigma_m (half its square each).
"""
import argparse
import sys

import numpy as np
from PIL import Image

from phase_correlation import phase_correlate


def shift(a, b):
    """(rows, cols) shift of b's content against a's and q, each image's mean taken out first."""
    dx, dy, q = phase_correlate(a - a.mean(), b - b.mean())
    return -dy, -dx, q


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--pixel-m", type=float, default=0.2, help="ground size of a pixel, metres")
    p.add_argument("--windows", default="64,128", help="window sizes in pixels, comma-separated")
    p.add_argument("--min-q", type=float, default=12.0)
    o = p.parse_args()
    try:
        A = np.asarray(Image.open(o.a).convert("L"), np.float64)
        B = np.asarray(Image.open(o.b).convert("L"), np.float64)
        sizes = [int(s) for s in o.windows.split(",")]
    except (OSError, ValueError) as e:
        sys.exit(f"local_coregistration: {e}")
    if A.shape != B.shape:
        sys.exit(f"local_coregistration: {o.a} is {A.shape[1]}x{A.shape[0]}, {o.b} {B.shape[1]}x{B.shape[0]}: not one grid")
    dy, dx, peak = shift(A, B)
    print(f"whole image: shift of b's content ({dx * o.pixel_m:.2f}, {dy * o.pixel_m:.2f}) m (columns, rows), q {peak:.1f}")
    for n in sizes:
        if n < 8 or n > min(A.shape):
            sys.exit(f"local_coregistration: window {n} px does not fit the {A.shape[1]}x{A.shape[0]} image")
        S = np.array([shift(A[y:y + n, x:x + n], B[y:y + n, x:x + n])
                      for y in range(0, A.shape[0] - n + 1, n // 2) for x in range(0, A.shape[1] - n + 1, n // 2)])
        good = S[:, 2] >= o.min_q
        if not good.any():
            print(f"{n} px windows ({n * o.pixel_m:.1f} m): none of {len(S)} has q >= {o.min_q:g}")
            continue
        d = np.hypot(S[good, 0], S[good, 1]) * o.pixel_m
        # The RMS per axis (the root of half the mean squared length): the one sigma per horizontal
        # axis of what the two images disagree on, as a map's registration_sigma_m pair sums it.
        rms = np.sqrt(np.mean(d ** 2) / 2)
        print(f"{n} px windows ({n * o.pixel_m:.1f} m), half-overlapping: {good.sum()} of {len(S)} with q >= {o.min_q:g}; shift "
              f"median {np.median(d):.2f} m, 75th percentile {np.percentile(d, 75):.2f}, 90th {np.percentile(d, 90):.2f}; "
              f"mean ({S[good, 1].mean() * o.pixel_m:.2f}, {S[good, 0].mean() * o.pixel_m:.2f}) m; RMS per axis {rms:.2f} m")


if __name__ == "__main__":
    main()
