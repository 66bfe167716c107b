#!/usr/bin/python3
"""Checks deep_iclk.widen_state, the warm start of a wider network (train_deep.py --widen):
the widened model must end where the narrow one ends, and its new channels must be free to
learn; and deep_iclk.narrow_state (train_deep.py --narrow), which must undo a widening bit for
bit. Offline, like the rest of training/ (Debian's python3-torch; not part of the C++ suite):

  /usr/bin/python3 training/test_widen.py [weights/deep_iclk_s16.tlw]

On a synthetic pair (a smooth random texture at 800 m, the live image shifted by a few
pixels) the shipped s16 tensors and their widening to s16w48 and s16w64 must give the same
pose within 1e-5 rad and 1e-3 m: the two differ only in float rounding (a group's mean is
scaled by old width / new width, which the per-channel normalisation takes out again). Then
one gradient step of the 3-D EPE must reach the weights that read the new channels, which
start at zero (were they stuck there, the widening would add nothing).
"""
import os
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deep_iclk as D  # noqa: E402
import tlw  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def synthetic_pair(B=2, H=240, W=376):
    g = torch.Generator().manual_seed(3)
    base = torch.nn.functional.interpolate(torch.rand(B, 3, 30, 47, generator=g) * 255, size=(H, W), mode="bilinear",
                                           align_corners=False)
    live = torch.roll(base, (2, 3), (2, 3))
    depth = torch.full((B, 1, H, W), 800.0)
    K = tuple(torch.full((B,), v) for v in (325.6, 325.6, 187.5, 119.5))
    # The truth for the gradient check: the roll moves the image by (3, 2) px at 800 m.
    truth = (torch.eye(3).repeat(B, 1, 1), torch.tensor([[3 * 800 / 325.6, 2 * 800 / 325.6, 0.0]] * B))
    return base, depth, live, K, truth


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "weights/deep_iclk_s16.tlw")
    src = {k: torch.from_numpy(v) for k, v in tlw.read(path).items()}
    narrow = D.DeepICLK("s16", iterations=20, channels=2)
    narrow.load_state_dict(src)
    ref, depth, live, K, truth = synthetic_pair()
    with torch.no_grad():
        R0, t0, _, _ = narrow(ref, depth, live, K)
    assert t0.norm(dim=1).min() > 1.0, "the synthetic pair should move the answer away from the identity"
    for size in ("s16w48", "s16w64"):
        wide = D.DeepICLK(size, iterations=20, channels=2)
        wide.load_state_dict(D.widen_state(src, wide, torch.Generator().manual_seed(1)))
        with torch.no_grad():
            R1, t1, _, _ = wide(ref, depth, live, K)
        dR = D.so3_log(R1 @ R0.transpose(1, 2)).norm(dim=1).max().item()
        dt = (t1 - t0).norm(dim=1).max().item()
        print(f"{size}: the widened model ends {dR:.2e} rad and {dt:.2e} m from s16's answer")
        assert dR < 1e-5 and dt < 1e-3, f"{size}: widen_state changed the function"
        # The new channels' outgoing weights start at zero; one step's gradient must reach them.
        wide.iterations = 5
        _, _, losses, _ = wide(ref, depth, live, K, truth=truth)
        torch.stack(losses).sum().backward()
        conv = wide.encoder.levels[2][1][0]  # e2_1: reads e2_0's 64 or 48 outputs, 32 of them new or old
        old = src["encoder.levels.2.1.0.weight"].shape[1]
        fresh = conv.weight.grad[:, old:].abs().max().item()
        assert (conv.weight[:, old:] == 0).all(), f"{size}: e2_1's weights on the new channels should start at zero"
        assert fresh > 0, f"{size}: no gradient reaches e2_1's weights on the new channels"
        print(f"{size}: the largest gradient on e2_1's weights from new channels {fresh:.2e}")
    print("widen_state: ok")
    # narrow_state, its inverse where there is one: widening adds channels nothing reads (their
    # outgoing weights are zero), so their scores are zero, and narrowing the widened tensors back
    # to s16 must keep exactly s16's channels in s16's order: the same tensors, bit for bit.
    for size in ("s16w48", "s16w64"):
        wide = D.DeepICLK(size, iterations=20, channels=2)
        wide.load_state_dict(D.widen_state(src, wide, torch.Generator().manual_seed(1)))
        back = D.narrow_state(wide.state_dict(), narrow)
        differ = [k for k in src if not torch.equal(back[k], src[k])]
        assert not differ, f"{size} -> s16: narrow_state did not recover s16's tensors: {differ[:3]}"
        print(f"{size} -> s16: narrow_state recovers s16's {len(src)} tensors bit for bit")
    # s16w64 -> s8w48m8 (train_deep.py --narrow's use): every shape checked by load_state_dict;
    # s16 -> s8w48m8 must be refused (s16's levels 2-4 are 32 wide, s8w48m8's 48), naming the conv.
    w64 = {k: torch.from_numpy(v) for k, v in tlw.read(os.path.join(ROOT, "weights/deep_iclk_s16w64.tlw")).items()}
    small = D.DeepICLK("s8w48m8", iterations=20, channels=2)
    small.load_state_dict(D.narrow_state(w64, small))
    try:
        D.narrow_state(src, small)
        raise AssertionError("narrow_state made 48 channels of s16's 32")
    except ValueError as e:
        assert "encoder.levels.2.0.0 is 32 x 16 in the source, 48 x 16 here" in str(e), e
    print("narrow_state: ok")


if __name__ == "__main__":
    main()
