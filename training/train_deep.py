#!/usr/bin/python3
"""Trains terralign's learned tracker (training/deep_iclk.py) on pairs written by
`terralign dataset`, on the CPU, with checkpoints that let a run resume (also elsewhere).

  /usr/bin/python3 training/train_deep.py --data DIR --out training/runs/NAME [--size s16]
      [--steps 3000] [--batch 4] [--iterations 5] [--lr 5e-4] [--seed 1] [--resume]

Each step takes `batch` pairs at random: a training pose, a reference year and a query year
(cross-year with probability 0.8, same year otherwise). The solver is unrolled for
`iterations` per level while training (20 at test time). Loss: the 3-D EPE after each level,
summed, as the paper (with --anchor-w W, plus W x each level's drift from a start at the
truth: DeepICLK.forward's anchor_iterations); a sample whose EPE is not finite is left out of
the step. Every --val-every steps the validation strip's cross-year pairs (a fixed subset)
are aligned with 20 iterations and the init / final EPE mean and median logged to
OUT/log.csv; OUT/curves.png plots them; OUT/last.pt is the checkpoint, OUT/best.pt the best validation median.
"""
import argparse
import csv
import os
import random
import subprocess
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deep_iclk as D  # noqa: E402
import tlw  # noqa: E402


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    if kind != b"Pf":
        raise ValueError(f"{path}: not a one-channel PFM")
    return np.flipud(data.reshape(h, w)).astype(np.float32)


def read_png(path):
    from PIL import Image
    return np.array(Image.open(path).convert("RGB"))


class PairSet:
    """Every pose of one split, loaded into memory: per pose the reference images per year,
    the reference depth, the query images per year, intrinsics and T_query_ref."""

    def __init__(self, root, split):
        rows = [r for r in csv.DictReader(open(os.path.join(root, "index.csv"))) if r["split"] == split]
        if not rows:
            raise SystemExit(f"{root}/index.csv has no '{split}' rows")
        self.layers = sorted({r["ref_layer"] for r in rows})
        poses = {}
        for r in rows:
            poses.setdefault(r["pose"], r)
        self.ids = sorted(poses)
        n, L = len(self.ids), len(self.layers)
        first = poses[self.ids[0]]
        h, w = int(first["height"]), int(first["width"])
        self.ref = np.zeros((n, L, h, w, 3), np.uint8)
        self.query = np.zeros((n, L, h, w, 3), np.uint8)
        self.depth = np.zeros((n, h, w), np.float32)
        self.K = np.zeros((n, 4), np.float64)
        self.T = np.zeros((n, 7), np.float64)
        self.up = np.zeros((n, 3), np.float64)  # the world's up in the reference (prior) camera
        self.altitude = np.zeros(n)
        t0 = time.time()
        for i, pid in enumerate(self.ids):
            r = poses[pid]
            d = os.path.join(root, split, pid)
            for k, lay in enumerate(self.layers):
                self.ref[i, k] = read_png(os.path.join(d, f"ref_{lay}.png"))
                self.query[i, k] = read_png(os.path.join(d, f"query_{lay}.png"))
            self.depth[i] = read_pfm(os.path.join(d, "ref_depth.pfm"))
            self.K[i] = [float(r[k]) for k in ("fx", "fy", "cx", "cy")]
            self.T[i] = [float(r[k]) for k in ("t_x", "t_y", "t_z", "q_w", "q_x", "q_y", "q_z")]
            self.altitude[i] = float(r["altitude"])
            q = torch.tensor([[float(v) for v in r["prior"].split()[3:7]]], dtype=torch.float64)
            self.up[i] = D.quat_to_R(q)[0, 2].numpy()  # R_W_C^T (0, 0, 1): R's third row
        print(f"{split}: {n} poses x {L} layers ({', '.join(self.layers)}) of {w}x{h} in {time.time() - t0:.0f} s",
              flush=True)

    def batch(self, items, dtype=torch.float32):
        """items: list of (pose index, ref layer index, query layer index)."""
        i = [a for a, _, _ in items]
        ref = torch.from_numpy(np.stack([self.ref[a, b] for a, b, _ in items])).permute(0, 3, 1, 2).to(dtype)
        qry = torch.from_numpy(np.stack([self.query[a, c] for a, _, c in items])).permute(0, 3, 1, 2).to(dtype)
        depth = torch.from_numpy(self.depth[i]).unsqueeze(1).to(dtype)
        K = tuple(torch.from_numpy(self.K[i][:, k]).to(dtype) for k in range(4))
        T = torch.from_numpy(self.T[i]).to(dtype)
        return ref, depth, qry, K, (D.quat_to_R(T[:, 3:]), T[:, :3])

    def up_of(self, items, dtype=torch.float32):
        return torch.from_numpy(self.up[[a for a, _, _ in items]]).to(dtype)


def augment(x, gen, p=0.8):
    """Photometric augmentation of a batch of images (B x 3 x H x W, 0..255), each image on
    its own with probability p: exposure gain (x0.7-1.4, log-uniform), white balance (each
    channel x0.85-1.15), saturation (x0.6-1.4), gamma (0.75-1.33, log-uniform), Gaussian blur
    (sigma 0.3-1.2 px, a third of the images) and sensor noise (sigma 0-4). Years differ in
    sensor, sun and season; these cover the first two, not the changes on the ground. Draws
    only from `gen`."""
    B = x.shape[0]
    u = lambda *shape: torch.rand(*shape, generator=gen, dtype=x.dtype)  # noqa: E731
    on = (u(B) < p).to(x.dtype).view(B, 1, 1, 1)
    gain = torch.exp(np.log(0.7) + u(B) * np.log(2.0)).view(B, 1, 1, 1)
    wb = (0.85 + 0.3 * u(B, 3)).view(B, 3, 1, 1)
    gamma = torch.exp((u(B) * 2 - 1) * np.log(1.33)).view(B, 1, 1, 1)
    sat = (0.6 + 0.8 * u(B)).view(B, 1, 1, 1)
    y = (x / 255.0).clamp(min=0).pow(gamma) * gain * wb * 255.0
    grey = y.mean(1, keepdim=True)
    y = grey + sat * (y - grey)
    blur = u(B) < 1.0 / 3
    sigma = 0.3 + 0.9 * u(B)
    if blur.any():
        k = torch.arange(-2, 3, dtype=x.dtype)
        for b in torch.nonzero(blur).flatten().tolist():
            g = torch.exp(-0.5 * (k / sigma[b]) ** 2)
            g = g / g.sum()
            img = y[b:b + 1].reshape(3, 1, *y.shape[2:])
            img = torch.nn.functional.conv2d(torch.nn.functional.pad(img, (2, 2, 0, 0), mode="replicate"), g.view(1, 1, 1, 5))
            img = torch.nn.functional.conv2d(torch.nn.functional.pad(img, (0, 0, 2, 2), mode="replicate"), g.view(1, 1, 5, 1))
            y[b] = img.reshape(3, *y.shape[2:])
    y = y + torch.randn(y.shape, generator=gen, dtype=x.dtype) * (4.0 * u(B)).view(B, 1, 1, 1)
    y = y.clamp(0, 255)
    return on * y + (1 - on) * x


def augment_survey(x, gen, p=0.5):
    """What differs between two surveys' orthophotos beyond augment()'s exposure and white
    balance (NAIP 2009 against 2020: 2009 pale and hazy, channel means 117/132/113 against
    77/97/75 at about the same spread): each image on its own with probability p gets a
    colour mix (the identity plus N(0, 0.08) per entry, rows keeping their sum), a gamma per
    channel (0.8-1.25, log-uniform), a contrast about the image's mean (x0.6-1.3) and haze
    (a blend of 0-35 % towards a pale grey-blue). Draws only from `gen`."""
    B = x.shape[0]
    u = lambda *shape: torch.rand(*shape, generator=gen, dtype=x.dtype)  # noqa: E731
    on = (u(B) < p).to(x.dtype).view(B, 1, 1, 1)
    mix = torch.eye(3, dtype=x.dtype).repeat(B, 1, 1) + 0.08 * torch.randn(B, 3, 3, generator=gen, dtype=x.dtype)
    mix = mix / mix.sum(2, keepdim=True)
    y = torch.einsum("bij,bjhw->bihw", mix, x / 255.0).clamp(min=0)
    gamma = torch.exp((u(B, 3) * 2 - 1) * np.log(1.25)).view(B, 3, 1, 1)
    y = y.pow(gamma)
    mean = y.mean((1, 2, 3), keepdim=True)
    y = mean + (0.6 + 0.7 * u(B)).view(B, 1, 1, 1) * (y - mean)
    haze = (0.35 * u(B)).view(B, 1, 1, 1)
    tint = (torch.tensor([0.72, 0.78, 0.76], dtype=x.dtype).view(1, 3, 1, 1) + 0.08 * (u(B, 3).view(B, 3, 1, 1) - 0.5))
    y = (1 - haze) * y + haze * tint
    y = (y * 255.0).clamp(0, 255)
    return on * y + (1 - on) * x


def near_start(truth, depth, gen, scale):
    """A start near the truth, as the eval protocol's prior (train_deep.py's pairs carry it)
    shrunk by `scale`: T_live_ref perturbed on the live side by a rotation of U[0, 6 scale]
    deg about a random axis and a move of U[0, 0.13 scale] x the median reference depth in a
    random direction. Trains the features to keep an answer a few pixels off where it is
    (docs/history.md, "Session 26"). Draws only from `gen`."""
    R_gt, t_gt = truth
    B, dtype = R_gt.shape[0], R_gt.dtype
    u = lambda *shape: torch.rand(*shape, generator=gen, dtype=dtype)  # noqa: E731
    unit = lambda: F.normalize(torch.randn(B, 3, generator=gen, dtype=dtype), dim=1)  # noqa: E731
    angle = u(B) * (6.0 * scale * np.pi / 180)
    dR, _ = D.se3_exp(torch.cat((unit() * angle.view(B, 1), torch.zeros(B, 3, dtype=dtype)), 1))
    med = torch.stack([d[torch.isfinite(d)].median() if torch.isfinite(d).any() else d.new_tensor(1.0)
                       for d in depth[:, 0]])
    move = unit() * (u(B) * 0.13 * scale * med).view(B, 1)
    return dR @ R_gt, (dR @ t_gt.unsqueeze(-1)).squeeze(-1) + move


def robust_epe(e, weight, scale):
    """The loss of 3-D EPEs e (metres, any shape) from a set whose pixel weighs `weight` metres of
    the main set's: weight e, or with scale C > 0 C log(1 + weight e / C), whose gradient halves at
    e = C. The protocol's success line, 5 px at 752 x 480, is about 6 m of NAIP ground at 800 m:
    with C near it the pairs that nearly succeed steer the training rather than the few that end
    50 m off (session 36)."""
    e = e * weight
    return scale * torch.log1p(e / scale) if scale > 0 else e


def year_gaps(layers):
    """|year_b - year_c| for every pair of layers named by year, or None when a name is not a year."""
    try:
        years = [int(n) for n in layers]
    except ValueError:
        return None
    return [[abs(y - z) for z in years] for y in years]


def sample_items(rng, n, L, count, cross=0.8, gaps=None, gap_power=0.0, min_gap=0):
    """count (pose, reference layer, query layer) triples. A cross-year pair (probability
    cross) draws its query year with weight gap^gap_power among the years at least min_gap
    from the reference's (uniformly when gaps is None or gap_power is 0)."""
    out = []
    while len(out) < count:
        a = rng.randrange(n)
        b = rng.randrange(L)
        c = b
        if L > 1 and rng.random() < cross:
            ks = [k for k in range(L) if k != b and (gaps is None or gaps[b][k] >= min_gap)]
            if not ks:
                continue
            if gaps is None or gap_power == 0:
                c = rng.choice(ks)
            else:
                c = rng.choices(ks, weights=[gaps[b][k] ** gap_power for k in ks])[0]
        out.append((a, b, c))
    return out


def validate(model, val, items, batch=8):
    model.eval()
    init, final = [], []
    with torch.no_grad():
        for s in range(0, len(items), batch):
            ref, depth, qry, K, truth = val.batch(items[s:s + batch])
            up = val.up_of(items[s:s + batch])
            B = ref.shape[0]
            eye = torch.eye(3).repeat(B, 1, 1)
            X0 = D.points(D.depth_pyramid(depth, 1)[0][0], K)
            valid = torch.isfinite(depth).float()
            init += D.epe(eye, torch.zeros(B, 3), truth[0], truth[1], X0, valid).tolist()
            R, t, _, _ = model(ref, depth, qry, K, up=up)
            final += D.epe(R, t, truth[0], truth[1], X0, valid).tolist()
    model.train()
    f = np.array(final)
    f = np.where(np.isfinite(f), f, 1e9)
    return float(np.mean(init)), float(np.median(init)), float(np.mean(np.minimum(f, 1e3))), float(np.median(f))


LOG_HEADER = "kind,step,loss,init_mean,init_median,final_mean,final_median,seconds\n"


def keep_log_until(path, step):
    """Drops the log's lines after `step` (written after the checkpoint a run resumes from, by a
    run killed between checkpoints, or cut off mid-line): the resumed run logs them again."""
    if not os.path.exists(path):  # a checkpoint moved without its log: the log starts again
        with open(path, "w") as f:
            f.write(LOG_HEADER)
        return
    with open(path) as f:
        lines = f.readlines()
    keep = lines[:1]
    for line in lines[1:]:
        fields = line.rstrip("\n").split(",")
        if line.endswith("\n") and len(fields) == 8 and fields[1].isdigit() and int(fields[1]) <= step:
            keep.append(line)
    with open(path + ".tmp", "w") as f:
        f.writelines(keep)
    os.replace(path + ".tmp", path)


def plot(out):
    rows = list(csv.DictReader(open(os.path.join(out, "log.csv"))))
    if not rows:
        return
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    tr = [r for r in rows if r["kind"] == "train"]
    va = [r for r in rows if r["kind"] == "val"]
    ax[0].plot([int(r["step"]) for r in tr], [float(r["loss"]) for r in tr], lw=0.8)
    ax[0].set_xlabel("step")
    ax[0].set_ylabel("training loss (m), 50-step mean:\nlevels' EPE e summed (C log(1 + e/C))")
    ax[0].set_yscale("log")
    for key, lab in (("init_median", "init median"), ("final_median", "NN (20) median"), ("final_mean", "NN (20) mean")):
        ax[1].plot([int(r["step"]) for r in va], [float(r[key]) for r in va], marker="o", label=lab)
    vf = [r for r in rows if r["kind"] == "val_far"]
    if vf:
        ax[1].plot([int(r["step"]) for r in vf], [float(r["final_median"]) for r in vf], marker="^", ls=":",
                   label="largest year gaps: NN (20) median")
    vx = [r for r in rows if r["kind"] == "val_extra"]
    for key, lab in (("init_median", "extra set: init median"), ("final_median", "extra set: NN (20) median")):
        if vx:
            ax[1].plot([int(r["step"]) for r in vx], [float(r[key]) for r in vx], marker="s", ls="--", label=lab)
    ax[1].set_xlabel("step")
    ax[1].set_ylabel("validation cross-year 3-D EPE (m)")
    ax[1].set_yscale("log")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(os.path.join(out, "curves.png"), dpi=90)
    plt.close(fig)


def host_record():
    """What decides a run's arithmetic besides its inputs, one line: PyTorch's version and
    threads, the CPU, the vector extensions by which oneDNN picks its convolution kernels, the
    caches (which may set their blocking), and an ISA cap set in the environment. Training
    gives the same bytes only where these agree: capping oneDNN at AVX2 (ONEDNN_MAX_CPU_ISA=AVX2)
    on the AVX-512 host of sessions 50-52 moved a run's first logged loss mean from 125.0034 to
    124.0071 (training/README.md, "What the same bytes need")."""
    model, flags = "?", set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model == "?":
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                    break
    except OSError:
        pass
    simd = [x for x in ("avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "amx_tile") if x in flags]
    caches = []
    for name, label in (("LEVEL1_DCACHE_SIZE", "L1d"), ("LEVEL2_CACHE_SIZE", "L2"), ("LEVEL3_CACHE_SIZE", "L3")):
        try:  # glibc's reading of CPUID, as oneDNN's
            size = int(subprocess.run(["getconf", name], capture_output=True, text=True, timeout=10).stdout.strip())
            caches.append(f"{label} {size // 1024} KiB")
        except (OSError, ValueError, subprocess.SubprocessError):
            continue
    caps = [f"{k}={os.environ[k]}" for k in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY")
            if k in os.environ]
    return (f"torch {torch.__version__}, {torch.get_num_threads()} threads, oneDNN "
            f"{'on' if torch.backends.mkldnn.is_available() else 'off'}; {model}; {' '.join(simd) or 'no AVX2'}; "
            f"{', '.join(caches) or 'caches unknown'}" + (f"; {' '.join(caps)}" if caps else ""))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--size", default="s16", choices=sorted(D.SIZES))
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--stop-at", type=int, default=0,
                   help="end the run after this step with a checkpoint (validated only where --val-every falls), "
                        "its learning-rate schedule still that of --steps: a run planned for --steps and stopped "
                        "for time, as several in training/README.md were, which --resume continues; 0: all --steps")
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--iterations", type=int, default=5)
    p.add_argument("--lr", type=float, default=5e-4)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--val-every", type=int, default=250)
    p.add_argument("--val-count", type=int, default=64)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--augment", type=float, default=0.0,
                   help="probability that each training image (reference and query, independently) is "
                        "augmented photometrically (augment(): exposure, white balance, saturation, gamma, blur, "
                        "noise); 0: none")
    p.add_argument("--augment-survey", type=float, default=0.0,
                   help="probability that each training image, independently, first gets augment_survey() (colour "
                        "mix, gamma per channel, contrast, haze: one survey's look against another's); 0: none")
    p.add_argument("--extra", help="a second dataset (terralign dataset's output) whose training pairs make a "
                        "whole batch with probability --extra-p; its loss is scaled by the ratio of the two sets' mean "
                        "altitudes, so a pixel of error weighs the same in both; its validation pairs are logged as "
                        "'val_extra' rows")
    p.add_argument("--extra-p", type=float, default=0.3)
    p.add_argument("--channels", type=int, default=1,
                   help="feature channels a level (each the mean of an equal group of the level's outputs); "
                        "1 is Lv et al.'s design; src/iclk/deep_aligner.cpp runs 1, 2 and 4; the shipped weights "
                        "have 2 since session 28")
    p.add_argument("--near-p", type=float, default=0.0,
                   help="probability that a batch starts near the truth (near_start()) instead of at the "
                        "prior the pairs were rendered at")
    p.add_argument("--near-scale", type=float, default=0.1,
                   help="the near start's perturbation as a fraction of the eval protocol's prior's")
    p.add_argument("--gap-power", type=float, default=0.0,
                   help="draw a cross-year pair's query year with weight (year gap)^P (0: uniformly); with "
                        "P > 0 the validation also logs 'val_far', pairs of the main set's largest year gaps")
    p.add_argument("--anchor-w", type=float, default=0.0,
                   help="weight of the anchor loss: at each level, the 3-D EPE after --anchor-iterations LM "
                        "steps started at the truth (DeepICLK.forward's anchor_iterations), summed over levels "
                        "and added to the loss; it pulls each level's learned minimum onto the truth")
    p.add_argument("--anchor-iterations", type=int, default=2)
    p.add_argument("--tilt-prior", type=float, default=0.0,
                   help="degrees: the LM holds the answer's roll and pitch to the prior's (the C++ solver's tilt "
                        "prior, terralign's default 3) in training and validation; 0: none")
    p.add_argument("--loss-scale", type=float, default=0.0,
                   help="metres: each level's 3-D EPE e enters the loss as C log(1 + e / C) (a Chch pair's e "
                        "first scaled by the sets' altitude ratio), whose pull is 1 / (1 + e / C): with C = 10, "
                        "0.6 at the 5 px line (6 m) and 0.14 at 60 m; 0: e itself")
    p.add_argument("--widen", action="store_true",
                   help="--init is a narrower network of the same family (s16 for s16w48): start from "
                        "deep_iclk.widen_state, which computes what it computes, its new channels free to learn")
    p.add_argument("--narrow", action="store_true",
                   help="--init is a wider network of the same family (s16w64 for s8w48m8): start from "
                        "deep_iclk.narrow_state, its strongest channels (magnitude pruning)")
    p.add_argument("--init", help="start from this checkpoint's (.pt) or weight file's (.tlw) weights where the shapes match (warm start)")
    a = p.parse_args()
    if a.widen and a.narrow:
        p.error("--widen and --narrow exclude each other")
    if (a.widen or a.narrow) and not a.init:
        p.error("--widen and --narrow need --init, the network to start from")
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    os.makedirs(a.out, exist_ok=True)
    train, val = PairSet(a.data, "train"), PairSet(a.data, "val")
    vrng = random.Random(12345)
    val_items = sample_items(vrng, len(val.ids), len(val.layers), a.val_count, cross=1.0)
    gaps = year_gaps(train.layers) if a.gap_power > 0 else None
    far_items = None
    if gaps is not None:
        far = max(max(g) for g in gaps) - 1  # the largest gap and the one below it
        far_items = sample_items(random.Random(54321), len(val.ids), len(val.layers), a.val_count // 2, cross=1.0,
                                 gaps=gaps, min_gap=far)
        print(f"gap power {a.gap_power}: cross-year pairs drawn by gap^{a.gap_power}; val_far: gaps >= {far} years",
              flush=True)
    extra = extra_val = extra_items = None
    if a.extra:
        extra, extra_val = PairSet(a.extra, "train"), PairSet(a.extra, "val")
        extra_items = sample_items(random.Random(12345), len(extra_val.ids), len(extra_val.layers), a.val_count, cross=1.0)
        extra_weight = float(train.altitude.mean() / extra.altitude.mean())
        print(f"extra set {a.extra}: batches with p = {a.extra_p}, loss x {extra_weight:.2f}", flush=True)
    model = D.DeepICLK(a.size, iterations=a.iterations, channels=a.channels)
    model.tilt_sigma = a.tilt_prior * np.pi / 180
    opt = torch.optim.Adam(model.parameters(), lr=a.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=a.steps, eta_min=a.lr * 0.05)
    step, best, acc, nacc = 0, float("inf"), 0.0, 0
    rng = random.Random(a.seed)
    gen = torch.Generator().manual_seed(a.seed)
    log_path = os.path.join(a.out, "log.csv")
    if a.resume and os.path.exists(os.path.join(a.out, "last.pt")):
        ck = torch.load(os.path.join(a.out, "last.pt"))
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["opt"])
        sched.load_state_dict(ck["sched"])
        step, best = ck["step"], ck["best"]
        acc, nacc = ck.get("acc", 0.0), ck.get("nacc", 0)  # a stop between two of the loss's log lines
        keep_log_until(log_path, step)
        rng.setstate(ck["rng"])
        torch.set_rng_state(ck["torch_rng"])
        if "aug_rng" in ck:
            gen.set_state(ck["aug_rng"])
        print(f"resumed at step {step}", flush=True)
        with open(os.path.join(a.out, "host.txt"), "a") as f:
            f.write(f"resumed at step {step}: {host_record()}\n")
    else:
        if a.init:
            if a.init.endswith(".tlw"):  # shipped weights: the tensors are the state dict
                src = {k: torch.from_numpy(v) for k, v in tlw.read(a.init).items()}
            else:
                src = torch.load(a.init, map_location="cpu")["model"]
            own = model.state_dict()
            if a.narrow:
                model.load_state_dict(D.narrow_state(src, model))
                print(f"warm start from {a.init}, narrowed to {a.size} (its strongest channels)", flush=True)
            elif a.widen:
                model.load_state_dict(D.widen_state(src, model, torch.Generator().manual_seed(a.seed)))
                print(f"warm start from {a.init}, widened to {a.size} (the same function)", flush=True)
            else:
                take = {k: v for k, v in src.items() if k in own and own[k].shape == v.shape}
                model.load_state_dict(take, strict=False)
                print(f"warm start from {a.init}: {len(take)} of {len(own)} tensors", flush=True)
        with open(log_path, "w") as f:
            f.write(LOG_HEADER)
        with open(os.path.join(a.out, "config.txt"), "w") as f:
            f.write(" ".join(sys.argv) + "\n")
        with open(os.path.join(a.out, "host.txt"), "w") as f:
            f.write(f"started: {host_record()}\n")
    end = min(a.steps, a.stop_at) if a.stop_at > 0 else a.steps
    t0 = time.time()
    while step < end:
        src, weight = train, 1.0
        if extra is not None and rng.random() < a.extra_p:
            src, weight = extra, extra_weight
        items = sample_items(rng, len(src.ids), len(src.layers), a.batch, gaps=gaps if src is train else None,
                             gap_power=a.gap_power)
        ref, depth, qry, K, truth = src.batch(items)
        if a.augment_survey > 0:
            ref, qry = augment_survey(ref, gen, a.augment_survey), augment_survey(qry, gen, a.augment_survey)
        if a.augment > 0:
            ref, qry = augment(ref, gen, a.augment), augment(qry, gen, a.augment)
        R_start = t_start = None  # the prior the pair was rendered at (identity)
        if a.near_p > 0 and rng.random() < a.near_p:
            R_start, t_start = near_start(truth, depth, gen, a.near_scale)
        anchor = a.anchor_iterations if a.anchor_w > 0 else 0
        _, _, losses, _ = model(ref, depth, qry, K, R0=R_start, t0=t_start, truth=truth, anchor_iterations=anchor,
                                up=src.up_of(items))
        per = robust_epe(torch.stack(losses), weight, a.loss_scale).sum(0)
        if anchor:
            per = per + a.anchor_w * robust_epe(torch.stack(model.anchor_losses), weight, a.loss_scale).sum(0)
        ok = torch.isfinite(per)
        if ok.any():
            loss = per[ok].mean()
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
            acc += loss.item()
            nacc += 1
        sched.step()
        step += 1
        if step % 50 == 0 and nacc:
            with open(log_path, "a") as f:
                f.write(f"train,{step},{acc / nacc:.4f},,,,,{time.time() - t0:.0f}\n")
            print(f"step {step} loss {acc / nacc:.3f} ({time.time() - t0:.0f} s)", flush=True)
            acc, nacc = 0.0, 0
        validating = step % a.val_every == 0 or step == a.steps
        if validating:
            def validation(kind, pairs, items):  # 20 iterations, as at test time; logged and printed
                model.iterations = 20
                im, imed, fm, fmed = validate(model, pairs, items)
                model.iterations = a.iterations
                with open(log_path, "a") as f:
                    f.write(f"{kind},{step},,{im:.3f},{imed:.3f},{fm:.3f},{fmed:.3f},{time.time() - t0:.0f}\n")
                print(f"{kind} {step}: init EPE mean {im:.2f} median {imed:.2f} m -> NN(20) mean {fm:.2f} "
                      f"median {fmed:.2f} m", flush=True)
                return fmed

            fmed = validation("val", val, val_items)
            if far_items is not None:
                validation("val_far", val, far_items)
            if extra is not None:
                validation("val_extra", extra_val, extra_items)
        # A run stopped by --stop-at between validations checkpoints without one: resumed, it
        # goes on as the run that was not stopped (validation draws no random numbers).
        if validating or step == end:
            state = {"model": model.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(), "step": step,
                     "best": min(best, fmed) if validating else best, "rng": rng.getstate(),
                     "torch_rng": torch.get_rng_state(), "size": a.size, "channels": a.channels,
                     "aug_rng": gen.get_state(), "acc": acc, "nacc": nacc}
            if validating and fmed < best:
                best = fmed
                torch.save(state, os.path.join(a.out, "best.pt.tmp"))
                os.replace(os.path.join(a.out, "best.pt.tmp"), os.path.join(a.out, "best.pt"))
            torch.save(state, os.path.join(a.out, "last.pt.tmp"))
            os.replace(os.path.join(a.out, "last.pt.tmp"), os.path.join(a.out, "last.pt"))
            plot(a.out)


if __name__ == "__main__":
    main()
