#!/usr/bin/python3
"""Would a converged test on more of the tracker's numbers keep more right answers than the
agreement test alone? Session 37's check (docs/history.md, "Session 37").

For each set of per-pose numbers that `terralign eval --json` writes (disagreement_px,
sharpness, residual_final, ...), fits a logistic model of "within 5 px" on the converged
answers of the --fit files (the training years' map, training/naip_train_years.json, so that
no eval year chooses the model), sets its threshold by the agreement threshold's rule (keep 97 %
of the right converged answers of the --calibrate file: 2016 -> 2017, seed 11) and prints, for
each --test file, the answers it keeps that are right (as % of all poses) and the share of the
kept that are right. The set `disagreement_px` alone is the shipped test.

The eval runs must count every answer (`--max-disagreement -1`), so that the test decides here:

  tl=build/release/tools/terralign/terralign
  $tl eval --map training/naip_train_years.json --camera data/cameras/uav_752x480.json \\
    --altitude 700:900 --tilt 10 --ref-layer 2010 --query-layer 2019 --count 200 --seed 11 \\
    --threads 2 --methods init,nn:20 --max-disagreement -1 --json fit_2010_2019.json
  ... (the README's pairs for --calibrate and --test)
  /usr/bin/python3 training/converged_test_features.py --fit fit_*.json \\
    --calibrate adj_11.json --test adj_7.json far_7.json ...

numpy only (Debian's python3-numpy).
"""
import argparse
import json

import numpy as np

FEATURES = ["disagreement_px", "sharpness", "residual_final", "residual_correlation", "iterations",
            "sigma_angle_deg", "sigma_position_m"]
LOG = {"disagreement_px", "residual_final", "sigma_angle_deg", "sigma_position_m"}  # fitted on their logs
SETS = [
    ["disagreement_px"],
    ["disagreement_px", "sharpness"],
    ["disagreement_px", "iterations"],
    ["disagreement_px", "residual_correlation"],
    ["disagreement_px", "sharpness", "residual_final"],
    ["disagreement_px", "sharpness", "residual_final", "residual_correlation"],
    ["disagreement_px", "sigma_angle_deg", "sigma_position_m"],
    FEATURES,
]


def load(paths, method):
    """The converged answers' numbers (one row each) and whether each is within 5 px."""
    rows, right = [], []
    for path in paths:
        with open(path) as f:
            samples = json.load(f)["methods"][method]["samples"]
        for s in samples:
            if not s["converged"]:
                continue
            # No disagreement_px: the second start failed, the worst case.
            rows.append([s.get(k, 1e3 if k == "disagreement_px" else np.nan) for k in FEATURES])
            right.append(s["epe_px"] < 5)
    return np.array(rows, float), np.array(right, bool)


def columns(X, names):
    out = []
    for k in names:
        v = X[:, FEATURES.index(k)]
        if k in LOG:
            v = np.log(np.minimum(v, 1e3) + 1e-3)
        out.append(v)
    return np.stack(out, 1)


def fit(F, y, l2=1e-2):
    """Logistic regression by Newton's method on standardised columns, a little ridge."""
    mu, sd = F.mean(0), F.std(0) + 1e-9
    Z = np.hstack([(F - mu) / sd, np.ones((len(F), 1))])
    w = np.zeros(Z.shape[1])
    for _ in range(50):
        p = 1 / (1 + np.exp(-Z @ w))
        H = Z.T @ (Z * (p * (1 - p))[:, None]) + l2 * np.eye(len(w))
        w -= np.linalg.solve(H, Z.T @ (p - y) + l2 * w)
    return lambda G: np.hstack([(G - mu) / sd, np.ones((len(G), 1))]) @ w


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fit", nargs="+", required=True, help="eval JSONs the model is fitted on")
    p.add_argument("--calibrate", required=True, help="eval JSON whose right answers set the threshold")
    p.add_argument("--test", nargs="+", required=True, help="eval JSONs to report")
    p.add_argument("--keep", type=float, default=0.97, help="share of the calibration's right answers kept")
    p.add_argument("--method", default="nn:20")
    a = p.parse_args()
    Xf, yf = load(a.fit, a.method)
    Xc, yc = load([a.calibrate], a.method)
    tests = []
    for path in a.test:
        with open(path) as f:
            poses = len(json.load(f)["methods"][a.method]["samples"])
        tests.append((path, poses) + load([path], a.method))
    print("| numbers | " + " | ".join(t[0] for t in tests) + " |")
    print("|---|" + "---|" * len(tests))
    for names in SETS:
        score = fit(columns(Xf, names), yf.astype(float))
        threshold = np.quantile(score(columns(Xc, names))[yc], 1 - a.keep)
        cells = []
        for _, poses, X, y in tests:
            kept = score(columns(X, names)) >= threshold
            right = (kept & y).sum()
            cells.append(f"{100 * right / poses:.1f} % ({100 * right / max(kept.sum(), 1):.0f} % right)")
        print(f"| {' + '.join(names)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
