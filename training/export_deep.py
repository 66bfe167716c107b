#!/usr/bin/python3
"""Writes a trained learned-tracker checkpoint (training/train_deep.py) as a terralign weight
file (.tlw) that `terralign align --method nn --weights FILE` reads.

  /usr/bin/python3 training/export_deep.py CHECKPOINT.pt OUT.tlw [--note "data, licence, commit"]

The architecture text holds two networks, `encoder` (input x: 3 channels, normalised RGB;
outputs f0..fN-1: the features of each level, one channel, or K from train_deep.py --channels K,
each the mean of an equal group of the level's outputs) and `mestimator` (input x: |r|, f_ref, f_live,
w_prev; output w), and comment lines the C++ reads: `# input-scale 0.5` (the working
resolution relative to the camera) and `# levels N` (the encoder's and the solver's).
"""
import argparse
import os
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deep_iclk as D  # noqa: E402
import tlw  # noqa: E402

INPUT_SCALE = 0.5  # training/README.md: the dataset is rendered at half the camera's size


def architecture(size, note, channels=1):
    enc = D.SIZES[size]["encoder"]
    a, b, c = D.SIZES[size]["mest"]
    lines = ["terralign-net 1", f"# terralign learned tracker, size {size}", f"# input-scale {INPUT_SCALE}",
             f"# levels {len(enc)}"]
    lines += [f"# {n}" for n in note.splitlines() if n.strip()]
    lines += ["", "net encoder", "input x 3"]
    prev, outs = "x", []
    for level, widths in enumerate(enc):
        if level > 0:
            lines.append(f"pool p{level} {prev}")
            prev = f"p{level}"
        for k, dil in enumerate(D.ENCODER_DILATIONS):
            name = f"e{level}_{k}"
            lines.append(f"conv {name} {prev} {widths[k + 1]} {dil} elu encoder.levels.{level}.{k}.0")
            prev = name
        lines.append(f"mean f{level} {prev}" + (f" {channels}" if channels > 1 else ""))
        outs.append(f"f{level}")
    lines.append("output " + " ".join(outs))
    lines += ["", "net mestimator", "input x 4",
              f"conv m0 x {a} {D.MEST_DILATIONS[0]} elu mest.net.0.0",
              f"conv m1 m0 {b} {D.MEST_DILATIONS[1]} elu mest.net.1.0",
              f"conv m2 m1 {c} {D.MEST_DILATIONS[2]} elu mest.net.2.0",
              f"conv m3 m2 1 {D.MEST_DILATIONS[3]} none mest.net.3",
              "sigmoid w m3", "output w"]
    return "\n".join(lines) + "\n"


# The comment lines architecture() and calibrate_sharpness.py write themselves; the rest is the note.
OWN_LINES = ("# terralign learned tracker", "# input-scale", "# levels", "# max-disagreement-px", "# agree-px",
             "# min-sharpness", "# checkpoint step")


def note_of(path):
    """The note another weight file was exported with (to export a retrained file as it was)."""
    arch, _ = tlw.architecture(path)
    return "\n".join(l[2:] for l in arch.splitlines() if l.startswith("# ") and not l.startswith(OWN_LINES))


def export(state, size, dst, note="", channels=1):
    tensors = [(k, v.detach().numpy()) for k, v in state.items()]
    tlw.write(dst, architecture(size, note, channels), tensors)
    return len(tensors), sum(t.size for _, t in tensors)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint")
    p.add_argument("out")
    p.add_argument("--note", default="")
    p.add_argument("--note-from", help="take the note of this weight file (training/reproduce.sh: the committed one's)")
    a = p.parse_args()
    if a.note_from:
        a.note = note_of(a.note_from)
    ck = torch.load(a.checkpoint, map_location="cpu")
    k = ck.get("channels", 1)
    if k not in (1, 2, 4):
        sys.exit(f"export_deep: {a.checkpoint} has {k} feature channels a level; the C++ learned tracker "
                 "(src/iclk/deep_aligner.cpp) runs 1, 2 or 4")
    n, params = export(ck["model"], ck["size"], a.out, a.note + f"\ncheckpoint step {ck['step']}", k)
    print(f"{a.out}: {n} tensors, {params} parameters (size {ck['size']}, step {ck['step']})")


if __name__ == "__main__":
    main()
