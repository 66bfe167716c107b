#!/usr/bin/python3
"""Converts Lv et al.'s published checkpoint to terralign's weight format, folding each
BatchNorm into its convolution: w' = w * g / sqrt(var + eps), b' = beta - mean * g / sqrt(var + eps).

  /usr/bin/python3 training/convert_lv19.py ../shared/anchors/lv19/TUM_RGBD_ABC_final.pth.tar weights/lv19_tum_abc.tlw
"""
import sys

import torch

import lv19
import tlw

EPS = 1e-5  # nn.BatchNorm2d's default, which the checkpoint was trained with


def fold(sd, prefix):
    w = sd[prefix + ".0.weight"]
    g, b = sd[prefix + ".1.weight"], sd[prefix + ".1.bias"]
    mean, var = sd[prefix + ".1.running_mean"], sd[prefix + ".1.running_var"]
    scale = g / torch.sqrt(var + EPS)
    return (w * scale.view(-1, 1, 1, 1)).numpy(), (b - mean * scale).numpy()


def architecture():
    lines = ["terralign-net 1", "", "net encoder", "input x 8"]
    prev, outs, feats = "x", [], []
    for level, widths in enumerate(lv19.Encoder.WIDTHS):
        if level > 0:
            lines.append(f"pool p{level} {prev}")
            prev = f"p{level}"
        for k, dil in enumerate((1, 2, 2)):
            name = f"e{level}_{k}"
            lines.append(f"conv {name} {prev} {widths[k + 1]} {dil} elu encoder.net{level}.{k}")
            prev = name
        lines.append(f"mean f{level} {prev}")
        outs.append(f"f{level}")
        feats.append(prev)
    lines.append("output " + " ".join(outs + feats))
    lines += ["", "net mestimator", "input x 4",
              "conv m0 x 16 1 elu mestimator.0",
              "conv m1 m0 32 2 elu mestimator.1",
              "conv m2 m1 64 4 elu mestimator.2",
              "conv m3 m2 1 1 elu mestimator.3",
              "sigmoid w m3",
              "output w"]
    return "\n".join(lines) + "\n"


def main(src, dst):
    sd = torch.load(src, map_location="cpu")["state_dict"]
    tensors = []
    for level in range(4):
        for k in range(3):
            w, b = fold(sd, f"encoder.net{level}.{k}")
            tensors += [(f"encoder.net{level}.{k}.weight", w), (f"encoder.net{level}.{k}.bias", b)]
    for k in range(4):
        w, b = fold(sd, f"mEst_func.net.{k}")
        tensors += [(f"mestimator.{k}.weight", w), (f"mestimator.{k}.bias", b)]
    tlw.write(dst, architecture(), tensors)
    print(f"{dst}: {len(tensors)} tensors, {sum(t.size for _, t in tensors)} parameters")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
