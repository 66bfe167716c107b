#!/usr/bin/env python3
"""The element-wise mean of weight files of one architecture (a "model soup": runs fine-tuned
from the same start lie in one basin, and their mean often generalises better than either).

  python3 training/average_weights.py A.tlw B.tlw [C.tlw ...] --out SOUP.tlw [--note TEXT]

The files must have the same network (their architecture text equal but for its comment
lines) and the same tensors. The output takes the first file's architecture with a note of
its parts, so also its calibrated thresholds (e.g. '# max-disagreement-px'): calibrate them
again (calibrate_sharpness.py) before shipping a mean. Needs numpy only (tlw.py)."""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tlw  # noqa: E402


def network_lines(arch):
    """The architecture text without its comment lines: what must match."""
    return [line for line in arch.splitlines() if not line.startswith("#")]


def average(paths):
    """(architecture of the first, [(name, mean array)]) of the files at paths."""
    archs = [tlw.architecture(p)[0] for p in paths]
    for p, a in zip(paths[1:], archs[1:]):
        if network_lines(a) != network_lines(archs[0]):
            raise ValueError(f"{p}: another network than {paths[0]}'s")
    parts = [tlw.read(p) for p in paths]
    names = list(parts[0])
    for p, t in zip(paths[1:], parts[1:]):
        if sorted(t) != sorted(names):
            raise ValueError(f"{p}: other tensors than {paths[0]}'s")
        for n in names:
            if t[n].shape != parts[0][n].shape:
                raise ValueError(f"{p}: tensor {n} is {t[n].shape}, {paths[0]}'s {parts[0][n].shape}")
    mean = [(n, (sum(t[n].astype(np.float64) for t in parts) / len(parts)).astype(np.float32)) for n in names]
    return archs[0], mean


def with_note(arch, note):
    """arch with `# note` lines after its existing header comments."""
    lines = arch.splitlines()
    k = 1
    while k < len(lines) and lines[k].startswith("#"):
        k += 1
    return "\n".join(lines[:k] + [f"# {n}" for n in note.splitlines() if n.strip()] + lines[k:]) + "\n"


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+")
    p.add_argument("--out", required=True)
    p.add_argument("--note", default="")
    a = p.parse_args()
    if len(a.inputs) < 2:
        sys.exit("average_weights: give at least two weight files")
    if os.path.abspath(a.out) in map(os.path.abspath, a.inputs):
        sys.exit(f"average_weights: --out {a.out} is one of the inputs")
    try:
        arch, mean = average(a.inputs)
    except (OSError, ValueError) as e:
        sys.exit(f"average_weights: {e}")
    note = "mean of " + ", ".join(os.path.basename(x) for x in a.inputs) + ("\n" + a.note if a.note else "")
    tlw.write(a.out, with_note(arch, note), mean)
    print(f"{a.out}: mean of {len(a.inputs)} files, {len(mean)} tensors, {sum(t.size for _, t in mean)} parameters")


if __name__ == "__main__":
    main()
