#!/usr/bin/env python3
"""Whether two weight files (.tlw) hold the same tensors: per tensor its name, shape and the
largest absolute difference; exit status 0 only where every tensor is the same bytes.

  /usr/bin/python3 training/same_tensors.py A.tlw B.tlw

training/reproduce.sh ends with it: the weight file it trained against the committed one.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tlw  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    a, b = tlw.read(sys.argv[1]), tlw.read(sys.argv[2])
    if set(a) != set(b):
        print(f"different tensor names: only in {sys.argv[1]}: {sorted(set(a) - set(b))}; "
              f"only in {sys.argv[2]}: {sorted(set(b) - set(a))}")
        return 1
    same, worst = 0, 0.0
    for name in a:
        x, y = a[name], b[name]
        if x.shape != y.shape:
            print(f"{name}: shape {x.shape} against {y.shape}")
            return 1
        d = float(np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)))) if x.size else 0.0
        if x.tobytes() == y.tobytes():
            same += 1
        else:
            print(f"{name} {tuple(x.shape)}: largest difference {d:.3g} (largest value {float(np.max(np.abs(y))):.3g})")
        worst = max(worst, d)
    print(f"{same} of {len(a)} tensors the same bytes; largest difference {worst:.3g}")
    return 0 if same == len(a) else 1


if __name__ == "__main__":
    sys.exit(main())
