#!/usr/bin/python3
"""PyTorch's time for Lv et al.'s encoder on the CPU, for bench_nn to compare against.
Prints one line: ms=<best of the fastest setting>. Tries contiguous and channels_last
memory formats and keeps the faster (the fair comparison is with PyTorch at its best).

  /usr/bin/python3 training/bench_torch_encoder.py WIDTH HEIGHT THREADS
"""
import os
import sys
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lv19  # noqa: E402


def main(w, h, threads):
    torch.set_num_threads(threads)
    torch.set_grad_enabled(False)
    enc = lv19.Encoder().eval()
    x = torch.randn(1, 8, h, w)
    best = float("inf")
    for fmt in (torch.contiguous_format, torch.channels_last):
        m = enc.to(memory_format=fmt)
        xi = x.contiguous(memory_format=fmt)
        m(xi)
        for _ in range(5):
            t0 = time.perf_counter()
            m(xi)
            best = min(best, (time.perf_counter() - t0) * 1000)
    print(f"ms={best:.3f}")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
