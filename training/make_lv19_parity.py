#!/usr/bin/python3
"""Writes the parity vectors for the C++ engine: Lv et al.'s encoder and M-estimator run in
PyTorch (float32, CPU) on two TUM example frames, resized to 160x120 as follows: colour by a
4x4 box average (avg_pool2d, exact for 640x480 -> 160x120), depth by taking every 4th pixel
(nearest), 16-bit depth / 5000 = metres, 0 = none.

Encoder input of a frame (8 channels): its normalised RGB and inverse depth, then the other
frame's. Stored: each frame's 4-channel input (in_a, in_b), each level's channel mean
(fa0..fa3, fb0..fb3) and the full level-3 features (ea3, eb3); the M-estimator run coarse to
fine on r = fb - fa with the previous weight upsampled bilinearly (align_corners=False; ones
at level 3): w0..w3. Tensors are C x H x W.

  /usr/bin/python3 training/make_lv19_parity.py ../shared/anchors/lv19 tests/data/nn/lv19_tum_parity.tlw
"""
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F

import lv19
import tlw


def read_png(path):
    try:
        from PIL import Image as I
        return np.array(I.open(path))
    except ImportError:
        raise SystemExit("python3-pil is needed: apt-get install python3-pil")


def main(root, dst):
    torch.set_grad_enabled(False)
    enc, mest = lv19.load_lv19(os.path.join(root, "TUM_RGBD_ABC_final.pth.tar"))
    frames = [("1305031790.645155", "1305031790.640468"), ("1305031790.713097", "1305031790.709421")]
    inputs = []
    for c, d in frames:
        rgb = torch.from_numpy(read_png(os.path.join(root, "tum_examples/color", c + ".png"))[:, :, :3].astype(np.float32))
        rgb = F.avg_pool2d(rgb.permute(2, 0, 1).unsqueeze(0), 4)
        depth = torch.from_numpy(read_png(os.path.join(root, "tum_examples/depth", d + ".png")).astype(np.float32) / 5000.0)
        depth = depth[::4, ::4].unsqueeze(0).unsqueeze(0)
        inputs.append(torch.cat((lv19.normalise_rgb(rgb), lv19.inverse_depth(depth)), dim=1))
    a, b = inputs
    fa = enc(torch.cat((a, b), 1))
    fb = enc(torch.cat((b, a), 1))
    ma = [f.mean(1, keepdim=True) for f in fa]
    mb = [f.mean(1, keepdim=True) for f in fb]
    ws = [None] * 4
    w = torch.ones_like(ma[3])
    for level in (3, 2, 1, 0):
        if level < 3:
            w = F.interpolate(ws[level + 1], size=ma[level].shape[-2:], mode="bilinear", align_corners=False)
        r = mb[level] - ma[level]
        ws[level] = mest(r.abs(), ma[level], mb[level], w)
    t = [("in_a", a[0]), ("in_b", b[0])]
    t += [(f"fa{l}", ma[l][0]) for l in range(4)] + [(f"fb{l}", mb[l][0]) for l in range(4)]
    t += [("ea3", fa[3][0]), ("eb3", fb[3][0])] + [(f"w{l}", ws[l][0]) for l in range(4)]
    tlw.write(dst, "parity vectors: Lv et al. ABC on TUM fr1 frames 1305031790.645155 and .713097, 160x120\n",
              [(n, x.numpy()) for n, x in t])
    print(dst, ", ".join(f"{n} {tuple(x.shape)}" for n, x in t))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
