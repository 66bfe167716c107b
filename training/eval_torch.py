#!/usr/bin/python3
"""The PyTorch model (training/deep_iclk.py) on pairs written by `terralign dataset`, to compare
checkpoints the converter has not written yet: one reference layer against one
query layer over every pose of the data set, from the rendered prior, 20 iterations a level,
no coarse search and no converged test (the C++ tracker has both: compare models here with
each other, not with `terralign eval`). Prints the 3-D EPE mean / median (m), the 2-D EPE
median at the camera's full width (px) and the share within 1 and 5 px there.

  /usr/bin/python3 training/eval_torch.py --data DIR --ref-layer 2009 --query-layer 2020 \\
      [--channels K] MODEL [MODEL ...]     # checkpoints (.pt) or weight files (.tlw)
"""
import argparse
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deep_iclk as D  # noqa: E402
from train_deep import PairSet  # noqa: E402


def px_error(R, t, R_gt, t_gt, X, valid, K):
    """Mean over valid X of the image distance between the projections of T X and T_gt X."""
    def proj(Rm, tm):
        Y = torch.einsum("bij,bjhw->bihw", Rm, X) + tm.view(-1, 3, 1, 1)
        z = Y[:, 2:3].clamp(min=1e-6)
        return torch.cat((K[0].view(-1, 1, 1, 1) * Y[:, 0:1] / z, K[1].view(-1, 1, 1, 1) * Y[:, 1:2] / z), 1)
    d = (proj(R, t) - proj(R_gt, t_gt)).norm(dim=1, keepdim=True)
    return (d * valid).sum((1, 2, 3)) / valid.sum((1, 2, 3)).clamp(min=1)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True)
    p.add_argument("--ref-layer", required=True)
    p.add_argument("--query-layer", required=True)
    p.add_argument("--full-width", type=int, default=752, help="the camera's width, for pixels at its size")
    p.add_argument("--channels", type=int, default=None,
                   help="run the models with this many feature channels a level (their outputs grouped; "
                        "default: each model's own)")
    p.add_argument("models", nargs="+")
    a = p.parse_args()
    torch.set_num_threads(2)
    sets = [PairSet(a.data, s) for s in ("train", "val") if any(
        l.startswith(s + ",") for l in open(os.path.join(a.data, "index.csv")))]
    for s in sets:
        if a.ref_layer not in s.layers or a.query_layer not in s.layers:
            sys.exit(f"eval_torch: {a.data} has layers {', '.join(s.layers)}, not {a.ref_layer} and {a.query_layer}")
    for path in a.models:
        model, _ = D.load_model(path, channels=a.channels)
        model.eval()
        epe, px = [], []
        with torch.no_grad():
            for s in sets:
                b, c = s.layers.index(a.ref_layer), s.layers.index(a.query_layer)
                for k in range(0, len(s.ids), 8):
                    ref, depth, qry, K, truth = s.batch([(i, b, c) for i in range(k, min(k + 8, len(s.ids)))])
                    X0 = D.points(D.depth_pyramid(depth, 1)[0][0], K)
                    valid = torch.isfinite(depth).float()
                    R, t, _, _ = model(ref, depth, qry, K)
                    epe += D.epe(R, t, truth[0], truth[1], X0, valid).tolist()
                    px += (px_error(R, t, truth[0], truth[1], X0, valid, K) * (a.full_width / ref.shape[-1])).tolist()
        e, q = np.nan_to_num(np.array(epe), nan=1e9), np.nan_to_num(np.array(px), nan=1e9)
        print(f"{path}: {a.ref_layer} -> {a.query_layer}, {len(e)} poses: 3-D EPE mean {np.mean(np.minimum(e, 1e4)):.2f} "
              f"median {np.median(e):.2f} m; 2-D EPE median {np.median(q):.2f} px; < 1 px {100 * np.mean(q < 1):.1f} %, "
              f"< 5 px {100 * np.mean(q < 5):.1f} %", flush=True)


if __name__ == "__main__":
    main()
