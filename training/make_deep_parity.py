#!/usr/bin/python3
"""Writes the learned tracker's parity vectors: validation pairs from a `terralign dataset`
folder, cropped to 192 x 128 around the centre (intrinsics shifted to match), aligned by
training/deep_iclk.py with the given weights (20 iterations per level, identity start), in
float32. tests/test_deep_iclk.cpp runs the C++ pipeline on the same inputs and weights and
compares the final pose (1e-4 rad, 1e-3 of the altitude).

  /usr/bin/python3 training/make_deep_parity.py MODEL DATASET_DIR OUT.tlw [--pairs 3]
  /usr/bin/python3 training/make_deep_parity.py MODEL VECTORS.tlw OUT.tlw [--channels K]
      [--keep-pairs | --skip-near-bound]

MODEL: a checkpoint (.pt) or a weight file (.tlw); --channels K runs it with K feature channels
a level (deep_iclk.load_model). With earlier vectors in place of the data set, their pairs are
aligned again and only the poses are written (R_k, t_k, wmean_k): a second model's parity on
the same committed images; --keep-pairs writes the pairs too, new vectors for new weights on
the old images (OUT may be VECTORS: the file is replaced whole or not at all).

Stored per pair k: ref_k (H x W x 3, 0..255), depth_k (H x W, metres, NaN: none),
live_k (H x W x 3), K_k (fx, fy, cx, cy), altitude_k, R_k and t_k (PyTorch's final
T_live_ref), gtR_k and gt_t_k (the truth, for information), and the per-level weights'
means wmean_k (4, finest first).
"""
import argparse
import os
import random
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deep_iclk as D  # noqa: E402
import tlw  # noqa: E402
from train_deep import PairSet  # noqa: E402

CROP_W, CROP_H = 192, 128


def epe_before_after(R, t, truth, depth, K):
    """3-D EPE (m) of one pair at the identity start and at (R, t)."""
    X = D.points(D.depth_pyramid(depth, 1)[0][0], K)
    valid = torch.isfinite(depth).float()
    e0 = D.epe(torch.eye(3).unsqueeze(0), torch.zeros(1, 3), truth[0], truth[1], X, valid).item()
    return e0, D.epe(R, t, truth[0], truth[1], X, valid).item()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model")
    p.add_argument("data")
    p.add_argument("out")
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--channels", type=int, default=None, help="feature channels a level (default: the model's)")
    p.add_argument("--keep-pairs", action="store_true", help="with VECTORS.tlw: write its pairs beside the new poses")
    p.add_argument("--skip-near-bound", action="store_true",
                   help="with VECTORS.tlw and no --keep-pairs: leave out the pairs on which the model steps near the "
                        "C++ solver's divergence bound, instead of stopping")
    p.add_argument("--max-ratio", type=float, default=0.25, help="keep pairs whose final EPE is below this x the initial")
    a = p.parse_args()
    torch.set_grad_enabled(False)
    model, (size, channels, step) = D.load_model(a.model, channels=a.channels)
    model.eval()
    if a.keep_pairs and a.skip_near_bound:
        raise SystemExit("make_deep_parity: --keep-pairs writes every pair; --skip-near-bound would leave one without a pose")
    if a.data.endswith(".tlw"):
        return again(model, a.data, a.out, f"{os.path.basename(a.model)} ({size}, {channels} channels, step {step})",
                     a.keep_pairs, a.skip_near_bound)
    val = PairSet(a.data, "val")
    rng = random.Random(a.seed)
    tensors, k, tried = [], 0, 0
    while k < a.pairs and tried < 400:
        tried += 1
        i, b = rng.randrange(len(val.ids)), rng.randrange(len(val.layers))
        c = rng.randrange(len(val.layers))  # cross-year or same-year: parity is about the arithmetic
        ref, depth, live, K, truth = val.batch([(i, b, c)])
        H, W = ref.shape[-2:]
        x0, y0 = (W - CROP_W) // 2, (H - CROP_H) // 2
        ref, live = ref[..., y0:y0 + CROP_H, x0:x0 + CROP_W], live[..., y0:y0 + CROP_H, x0:x0 + CROP_W]
        depth = depth[..., y0:y0 + CROP_H, x0:x0 + CROP_W]
        K = (K[0], K[1], K[2] - x0, K[3] - y0)
        R, t, _, ws = model(ref, depth, live, K, return_weights=True)
        e0, e = epe_before_after(R, t, truth, depth, K)
        # Only pairs the model aligns well, with no step near the C++ solver's divergence bound
        # (0.35): a diverging run is chaotic, and parity is about the arithmetic.
        if not (e < a.max_ratio * e0 and (e < 5.0 or a.max_ratio > 1)) or model.max_step.item() > 0.3:
            continue
        print(f"pair {k}: val pose {val.ids[i]}, {val.layers[b]} -> {val.layers[c]}, EPE {e0:.2f} -> {e:.3f} m")
        tensors += [(f"ref_{k}", ref[0].permute(1, 2, 0).numpy()), (f"depth_{k}", depth[0, 0].numpy()),
                    (f"live_{k}", live[0].permute(1, 2, 0).numpy()),
                    (f"K_{k}", np.array([float(v) for v in K], np.float32)),
                    (f"altitude_{k}", np.array([val.altitude[i]], np.float32)),
                    (f"R_{k}", R[0].numpy()), (f"t_{k}", t[0].numpy()),
                    (f"gtR_{k}", truth[0][0].numpy()), (f"gt_t_{k}", truth[1][0].numpy()),
                    (f"wmean_{k}", np.array([float(w.mean()) for w in ws], np.float32))]
        k += 1
    if k < a.pairs:
        raise SystemExit(f"only {k} of {a.pairs} pairs aligned well enough to serve as parity vectors")
    note = (f"parity vectors: the learned tracker ({size}, {channels} channels, step {step}) on {k} validation pairs of "
            f"{os.path.basename(os.path.normpath(a.data))}, {CROP_W}x{CROP_H}\n")
    tlw.write(a.out, note, tensors)
    print(f"{a.out}: {k} pairs")


def again(model, vectors, out, what, keep_pairs=False, skip_near_bound=False):
    """The pairs of earlier vectors aligned by `model`; its poses and weight means written, and
    with keep_pairs the pairs as well, in main()'s order. With skip_near_bound a pair on which
    `model` steps near the divergence bound gets no pose (R_k and t_k absent; the C++ test checks
    the pairs that have one)."""
    v = tlw.read(vectors)
    tensors, k, posed = [], 0, 0
    while f"ref_{k}" in v:
        img = lambda name: torch.from_numpy(v[f"{name}_{k}"]).permute(2, 0, 1).unsqueeze(0)  # noqa: E731
        ref, live = img("ref"), img("live")
        depth = torch.from_numpy(v[f"depth_{k}"]).unsqueeze(0).unsqueeze(0)
        K = tuple(torch.tensor([float(x)]) for x in v[f"K_{k}"])
        R, t, _, ws = model(ref, depth, live, K, return_weights=True)
        truth = (torch.from_numpy(v[f"gtR_{k}"]).unsqueeze(0), torch.from_numpy(v[f"gt_t_{k}"]).unsqueeze(0))
        e0, e = epe_before_after(R, t, truth, depth, K)
        print(f"pair {k}: EPE {e0:.2f} -> {e:.3f} m, largest step {model.max_step.item():.3f}")
        if model.max_step.item() > 0.3:  # as main(): a run near the divergence bound is chaotic
            if not skip_near_bound:
                raise SystemExit(f"pair {k}: a step of {model.max_step.item():.3f} is too near the C++ bound (0.35) "
                                 "for parity (--skip-near-bound leaves such pairs out)")
            print(f"pair {k}: left out (its largest step is near the C++ solver's divergence bound)")
            k += 1
            continue
        pose = [(f"R_{k}", R[0].numpy()), (f"t_{k}", t[0].numpy())]
        wmean = [(f"wmean_{k}", np.array([float(w.mean()) for w in ws], np.float32))]
        if keep_pairs:
            pair = [(f"{n}_{k}", v[f"{n}_{k}"]) for n in ("ref", "depth", "live", "K", "altitude")]
            tensors += pair + pose + [(f"{n}_{k}", v[f"{n}_{k}"]) for n in ("gtR", "gt_t")] + wmean
        else:
            tensors += pose + wmean
        k += 1
        posed += 1
    tlw.write(out, f"parity vectors: {what} on {posed} of the {k} pairs of {os.path.basename(vectors)}\n", tensors)
    print(f"{out}: poses of {posed} of {k} pairs")


if __name__ == "__main__":
    main()
