"""terralign's learned tracker in PyTorch: the same mathematics as the C++ pipeline
(src/iclk/deep_aligner.cpp on src/nn and src/iclk), so that weights trained here run
there and give the same pose (training/make_deep_parity.py checks it).

Per image pair (reference: rendered RGB + metric depth; live: camera RGB), at the working
resolution (half of 752x480):
  - colour normalisation (Lv et al.'s mean and std), the encoder: five levels of three 3x3
    convs (dilations 1, 2, 2; ELU), 2x2 average pooling between levels; each level's
    channels averaged to one feature image, or in K equal groups to K (`channels`; the
    shipped weights have 2 since session 28: each normalised on its own, residuals and
    Jacobians per channel, the M-estimator seeing their RMS |r| and their means);
  - per level, coarse to fine: the feature images are normalised (reference over its pixels
    with depth, live over all) to zero mean and unit variance; the reference pixels with a
    full 3x3 neighbourhood of depth (not on the border) are used; their Jacobians come from
    Sobel / 8 gradients of the reference features times d(u, v)/d(xi) at the identity;
  - the M-estimator sees |r| at the pose the level starts from, the two feature images and
    the previous level's weights (bilinear x2, ones at the coarsest) and gives w in (0, 1);
  - H = J^T W J once per level; each iteration: r = F_live(W(x; T)) - F_ref(x) (bilinear;
    pixels landing outside [0, w-1] x [0, h-1] drop out of H and g),
    delta = (H + lambda diag(H))^-1 J^T W r, T <- T exp(delta)^-1, xi = [omega; v];
  - the depth pyramid: each level's depth is the mean of the valid children.
Loss: 3-D EPE (metres, over the reference points with depth at full working resolution)
after each level, summed over levels, as in the paper.
"""
import torch
import torch.nn as nn
import torch.nn.functional as F

RGB_MEAN = (0.4914, 0.4822, 0.4465)
RGB_STD = (0.2023, 0.1994, 0.2010)

# Encoder widths per level (in, a, b, c) and M-estimator widths; the family is of Lv et al.'s
# structure, narrower, so that a 752x480 pair fits the onboard budget (README: trade-off).
# Five levels: at the working size (376 x 240) the priors of the eval protocol are off by
# about 25 px, 3 px at the fourth level, beyond a 3x3 gradient's reach; the fifth (23 x 15)
# brings that to 1.5 px (measured: with four levels the coarsest level halved the error only).
SIZES = {
    "s8": {"encoder": ((3, 8, 8, 8), (8, 16, 16, 16), (16, 16, 16, 16), (16, 16, 16, 16), (16, 16, 16, 16)),
           "mest": (8, 8, 8)},
    "s16": {"encoder": ((3, 16, 16, 16), (16, 16, 32, 32), (32, 32, 32, 32), (32, 32, 32, 32), (32, 32, 32, 32)),
            "mest": (16, 16, 16)},
    "s32": {"encoder": ((3, 16, 32, 32), (32, 32, 64, 64), (64, 64, 64, 64), (64, 64, 64, 64), (64, 64, 64, 64)),
            "mest": (16, 32, 32)},
    # s16 with its three coarsest levels wider (session 38): across a decade the coarse levels'
    # minima lie off the truth (docs/history.md, "Session 26"), and there pixels are cheap.
    "s16w48": {"encoder": ((3, 16, 16, 16), (16, 16, 32, 32), (32, 48, 48, 48), (48, 48, 48, 48), (48, 48, 48, 48)),
               "mest": (16, 16, 16)},
    "s16w64": {"encoder": ((3, 16, 16, 16), (16, 16, 32, 32), (32, 64, 64, 64), (64, 64, 64, 64), (64, 64, 64, 64)),
               "mest": (16, 16, 16)},
    # s16w64 narrowed where its pixels cost most on an AVX2 host (session 66): the two finest
    # levels and the M-estimator (which runs at every level's start) at 8 and 16 channels, levels
    # 2-4 at 48; about 0.7x s16w64's time a pair. A warm start from s16w64's strongest channels
    # (narrow_state), then training.
    "s8w48m8": {"encoder": ((3, 8, 8, 8), (8, 16, 16, 16), (16, 48, 48, 48), (48, 48, 48, 48), (48, 48, 48, 48)),
                "mest": (8, 8, 8)},
}
ENCODER_DILATIONS = (1, 2, 2)
MEST_DILATIONS = (1, 2, 4, 1)


def conv_block(cin, cout, dilation):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, 1, padding=dilation, dilation=dilation, bias=True), nn.ELU())


class Encoder(nn.Module):
    def __init__(self, widths, channels=1):
        super().__init__()
        self.widths, self.channels = widths, channels
        for w in widths:
            if w[-1] % channels:
                raise ValueError(f"{channels} feature channels do not divide a level's {w[-1]} outputs")
        self.levels = nn.ModuleList(
            nn.Sequential(*[conv_block(w[k], w[k + 1], d) for k, d in enumerate(ENCODER_DILATIONS)]) for w in widths)

    def forward(self, rgb):
        """rgb: N x 3 x H x W in 0..255 -> features per level, finest first: each level's
        outputs averaged in `channels` equal groups (1: all of them, Lv et al.'s design)."""
        mean = torch.tensor(RGB_MEAN, dtype=rgb.dtype).view(1, 3, 1, 1)
        std = torch.tensor(RGB_STD, dtype=rgb.dtype).view(1, 3, 1, 1)
        x = (rgb / 255.0 - mean) / std
        feats = []
        for level, net in enumerate(self.levels):
            if level > 0:
                x = F.avg_pool2d(x, 2)
            x = net(x)
            n, c, h, w = x.shape
            feats.append(x.view(n, self.channels, c // self.channels, h, w).mean(2))
        return feats


def narrow_state(src, model):
    """The state dict of `model` made of a subset of the wider `src`'s channels (a state dict of
    the same family: the same levels, dilations and feature channels, each conv at least as
    wide), a warm start for a narrower network: magnitude pruning, then training. A conv's kept
    output channels are those of the largest score, the L1 norm of the channel's filter times
    the L1 norm of the weights that read it in the next conv (1 where none does); the kept
    channels of a level's last conv are chosen group by group (model.encoder.channels groups of
    consecutive channels), so each feature channel is the mean of a subset of its old group.
    Every conv reads only its input's kept channels. This does not compute what `src` computes:
    it is the start of training, not its end."""
    own = model.state_dict()
    K = model.encoder.channels
    out = {}

    def keep(w, w_next, n, groups):
        score = w.abs().sum((1, 2, 3))
        if w_next is not None:
            score = score * w_next.abs().sum((0, 2, 3))
        o = w.shape[0]
        if o % groups or n % groups:
            raise ValueError(f"narrow_state: {groups} groups do not divide widths {o} -> {n}")
        go, gn = o // groups, n // groups
        idx = [g * go + torch.argsort(score[g * go:(g + 1) * go], descending=True, stable=True)[:gn].sort().values
               for g in range(groups)]
        return torch.cat(idx)

    def chain(keys, last_groups, next_of_last, prev=None):
        """Narrows the convs `keys` (in order, each reading the one before; the first reads the
        channels `prev` of its input, all where None); returns the last's kept output channels.
        next_of_last: the key of the conv that reads the last one, or None."""
        for i, key in enumerate(keys):
            w, b = src[key + ".weight"], src[key + ".bias"]
            n_out, n_in = own[key + ".weight"].shape[:2]
            if prev is not None:
                w = w[:, prev]
            if w.shape[0] < n_out or w.shape[1] != n_in:
                raise ValueError(f"narrow_state: {key} is {w.shape[0]} x {w.shape[1]} in the source, "
                                 f"{n_out} x {n_in} here")
            nxt = keys[i + 1] if i + 1 < len(keys) else next_of_last
            w_next = src[nxt + ".weight"] if nxt is not None else None
            groups = last_groups if i + 1 == len(keys) else 1
            kept = keep(w, w_next, n_out, groups) if n_out < w.shape[0] else torch.arange(w.shape[0])
            out[key + ".weight"], out[key + ".bias"] = w[kept].clone(), b[kept].clone()
            prev = kept
        return prev

    levels = len(model.encoder.widths)
    prev_level = None
    for level in range(levels):
        keys = [f"encoder.levels.{level}.{k}.0" for k in range(len(ENCODER_DILATIONS))]
        nxt = f"encoder.levels.{level + 1}.0.0" if level + 1 < levels else None
        prev_level = chain(keys, K, nxt, prev_level)  # a level reads the one below's kept outputs
    mkeys = [f"mest.net.{k}.0" for k in range(3)]
    kept = chain(mkeys, 1, "mest.net.3")
    out["mest.net.3.weight"] = src["mest.net.3.weight"][:, kept].clone()
    out["mest.net.3.bias"] = src["mest.net.3.bias"].clone()
    for key, v in own.items():
        if key not in out:
            raise ValueError(f"narrow_state: {key} has no source")
        if out[key].shape != v.shape:
            raise ValueError(f"narrow_state: {key} came out {tuple(out[key].shape)}, not {tuple(v.shape)}")
    return out


def widen_state(src, model, gen):
    """The state dict of `model` that computes what the narrower `src` (a state dict of the same
    family: the same levels, dilations and M-estimator, each encoder conv's width no larger)
    computes, a warm start for a wider network (Net2Net's idea, with zeros instead of copies).
    A conv's old output channels keep their weights; its new ones draw He-initialised weights
    from `gen`, and every conv reads a new input channel with weight zero, so new channels change
    nothing until training moves those zeros. The channels of a level's last conv are placed
    group by group (model.encoder.channels groups of consecutive channels, old then new in each)
    and their new channels start at zero weights and bias: a group's mean is then the old one
    times (old width / new width), which the solver's per-channel normalisation and the
    M-estimator (it sees normalised features) do not see."""
    own = model.state_dict()
    K = model.encoder.channels
    out = {}
    placement = {}  # conv prefix -> the new index of each old output channel

    def grouped(old, new):
        if old % K or new % K:
            raise ValueError(f"widen_state: {K} feature channels do not divide widths {old} -> {new}")
        go, gn = old // K, new // K
        return torch.tensor([(c // go) * gn + c % go for c in range(old)])

    prev_place = None  # the input channels' placement (None: the RGB input, unchanged)
    for level, widths in enumerate(model.encoder.widths):
        for k in range(len(ENCODER_DILATIONS)):
            key = f"encoder.levels.{level}.{k}.0"
            w_old, b_old = src[key + ".weight"], src[key + ".bias"]
            w_new = torch.empty_like(own[key + ".weight"])
            o_new, i_new = w_new.shape[:2]
            o_old, i_old = w_old.shape[:2]
            if o_old > o_new or i_old > i_new:
                raise ValueError(f"widen_state: {key} is {o_old} x {i_old} in the source, {o_new} x {i_new} here")
            last = k == len(ENCODER_DILATIONS) - 1
            place = grouped(o_old, o_new) if last else torch.arange(o_old)
            w_new.copy_(torch.randn(w_new.shape, generator=gen, dtype=w_new.dtype) * (2.0 / w_new[0].numel()) ** 0.5)
            b_new = torch.zeros(o_new, dtype=b_old.dtype)
            in_place = prev_place if prev_place is not None else torch.arange(i_old)
            fresh_in = torch.ones(i_new, dtype=torch.bool)
            fresh_in[in_place] = False
            w_new[:, fresh_in] = 0
            fresh_out = torch.ones(o_new, dtype=torch.bool)
            fresh_out[place] = False
            if last:
                w_new[fresh_out] = 0
            w_new[place[:, None], in_place[None, :]] = w_old
            b_new[place] = b_old
            out[key + ".weight"], out[key + ".bias"] = w_new, b_new
            placement[key] = place
            prev_place = place
    for key, v in own.items():
        if key not in out:
            if key not in src or src[key].shape != v.shape:
                raise ValueError(f"widen_state: {key} has no source of shape {tuple(v.shape)}")
            out[key] = src[key].clone()
    return out


class MEstimator(nn.Module):
    def __init__(self, widths):
        super().__init__()
        a, b, c = widths
        chans = (4, a, b, c)
        blocks = [conv_block(chans[k], chans[k + 1], MEST_DILATIONS[k]) for k in range(3)]
        self.net = nn.Sequential(*blocks, nn.Conv2d(c, 1, 3, 1, padding=1, bias=True), nn.Sigmoid())

    def forward(self, abs_r, f_ref, f_live, w_prev):
        return self.net(torch.cat((abs_r, f_ref, f_live, w_prev), dim=1))


# ---- SE(3), xi = [omega; v] ---------------------------------------------------------------

def hat(w):
    z = torch.zeros_like(w[..., 0])
    return torch.stack((torch.stack((z, -w[..., 2], w[..., 1]), -1),
                        torch.stack((w[..., 2], z, -w[..., 0]), -1),
                        torch.stack((-w[..., 1], w[..., 0], z), -1)), -2)


def se3_exp(xi):
    """xi: B x 6 -> (R: B x 3 x 3, t: B x 3). Series below 1e-2 rad (no NaN at zero)."""
    w, v = xi[:, :3], xi[:, 3:]
    th2 = (w * w).sum(-1)
    small = th2 < 1e-4
    th2s = torch.where(small, torch.ones_like(th2), th2)
    th = torch.sqrt(th2s)
    a = torch.where(small, 1 - th2 / 6 + th2 * th2 / 120, torch.sin(th) / th)
    b = torch.where(small, 0.5 - th2 / 24 + th2 * th2 / 720, (1 - torch.cos(th)) / th2s)
    c = torch.where(small, 1.0 / 6 - th2 / 120 + th2 * th2 / 5040, (th - torch.sin(th)) / (th2s * th))
    W = hat(w)
    W2 = W @ W
    eye = torch.eye(3, dtype=xi.dtype).expand_as(W)
    R = eye + a.view(-1, 1, 1) * W + b.view(-1, 1, 1) * W2
    V = eye + b.view(-1, 1, 1) * W + c.view(-1, 1, 1) * W2
    return R, (V @ v.unsqueeze(-1)).squeeze(-1)


def so3_log(R):
    """R: B x 3 x 3 -> its rotation vector, B x 3 (angles below pi)."""
    w = 0.5 * torch.stack((R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]), -1)
    s = w.norm(dim=-1)
    c = (R.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2
    small = s < 1e-6
    k = torch.where(small, 1 + s * s / 6, torch.atan2(s, c) / torch.where(small, torch.ones_like(s), s))
    return w * k.unsqueeze(-1)


def compose_inverse_exp(R, t, delta):
    """T <- T exp(delta)^-1."""
    Rd, td = se3_exp(delta)
    Rdi = Rd.transpose(1, 2)
    tdi = -(Rdi @ td.unsqueeze(-1)).squeeze(-1)
    return R @ Rdi, (R @ tdi.unsqueeze(-1)).squeeze(-1) + t


# ---- pyramids and the solver -----------------------------------------------------------------

def depth_pyramid(depth, levels):
    """depth: B x 1 x H x W, NaN where none -> per level (depth filled with 1, valid mask)."""
    valid = torch.isfinite(depth).to(depth.dtype)
    d = torch.where(valid > 0, depth, torch.zeros_like(depth))
    out = [(torch.where(valid > 0, d, torch.ones_like(d)), valid)]
    for _ in range(1, levels):
        s = F.avg_pool2d(d, 2) * 4
        n = F.avg_pool2d(valid, 2) * 4
        valid = (n > 0).to(depth.dtype)
        d = torch.where(n > 0, s / torch.where(n > 0, n, torch.ones_like(n)), torch.zeros_like(s))
        out.append((torch.where(valid > 0, d, torch.ones_like(d)), valid))
    return out


def half(K):
    fx, fy, cx, cy = K
    return (fx / 2, fy / 2, (cx + 0.5) / 2 - 0.5, (cy + 0.5) / 2 - 0.5)


def normalise(f, mask):
    """Zero mean, unit variance over mask (B x 1 x h x w), per image and channel; as the C++
    tracker (population variance)."""
    n = mask.sum((2, 3), keepdim=True).clamp(min=2)
    mean = (f * mask).sum((2, 3), keepdim=True) / n
    var = ((f * f) * mask).sum((2, 3), keepdim=True) / n - mean * mean
    return (f - mean) / torch.sqrt(var.clamp(min=1e-20))


def usable_mask(valid):
    """Pixels whose 3x3 neighbourhood has depth, not on the border."""
    m = -F.max_pool2d(-valid, 3, 1, 1)
    m[:, :, 0, :] = 0
    m[:, :, -1, :] = 0
    m[:, :, :, 0] = 0
    m[:, :, :, -1] = 0
    return m


def sobel(f):
    kx = torch.tensor([[-1.0, 0, 1], [-2, 0, 2], [-1, 0, 1]], dtype=f.dtype) / 8
    k = torch.stack((kx, kx.t())).unsqueeze(1)
    return F.conv2d(F.pad(f, (1, 1, 1, 1), mode="replicate"), k)


def pixel_grid(h, w, dtype):
    v, u = torch.meshgrid(torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij")
    return u.view(1, 1, h, w), v.view(1, 1, h, w)


def points(depth, K):
    fx, fy, cx, cy = K
    _, _, h, w = depth.shape
    u, v = pixel_grid(h, w, depth.dtype)
    return torch.cat((depth * (u - cx.view(-1, 1, 1, 1)) / fx.view(-1, 1, 1, 1),
                      depth * (v - cy.view(-1, 1, 1, 1)) / fy.view(-1, 1, 1, 1), depth), 1)


def jacobian(grad, X, K):
    """grad: B x 2 x h x w (Sobel / 8), X: B x 3 x h x w -> B x 6 x h x w (xi = [omega; v])."""
    fx, fy = K[0].view(-1, 1, 1, 1), K[1].view(-1, 1, 1, 1)
    x, y, z = X[:, 0:1], X[:, 1:2], X[:, 2:3]
    iz = 1 / z
    gx, gy = grad[:, 0:1] * fx * iz, grad[:, 1:2] * fy * iz
    xz, yz = x * iz, y * iz
    # d(u, v)/dY at Y = X, times [-[X]x | I].
    dz = -(gx * xz + gy * yz)  # coefficient of dY_z
    # -[X]x columns: (0, -z, y), (z, 0, -x), (-y, x, 0)
    j0 = -gy * z + dz * y
    j1 = gx * z - dz * x
    j2 = -gx * y + gy * x
    return torch.cat((j0, j1, j2, gx, gy, dz), 1)


def warp_sample(f_live, X, R, t, K):
    """Samples f_live at the projection of R X + t; returns (values, inside mask)."""
    B, _, h, w = X.shape
    Y = torch.einsum("bij,bjhw->bihw", R, X) + t.view(B, 3, 1, 1)
    z = Y[:, 2:3]
    ok = z > 1e-6
    zs = torch.where(ok, z, torch.ones_like(z))
    u = K[0].view(-1, 1, 1, 1) * Y[:, 0:1] / zs + K[2].view(-1, 1, 1, 1)
    v = K[1].view(-1, 1, 1, 1) * Y[:, 1:2] / zs + K[3].view(-1, 1, 1, 1)
    inside = ok & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    gu = torch.where(inside, u, torch.zeros_like(u)) * (2.0 / (w - 1)) - 1
    gv = torch.where(inside, v, torch.zeros_like(v)) * (2.0 / (h - 1)) - 1
    grid = torch.cat((gu, gv), 1).permute(0, 2, 3, 1)
    val = F.grid_sample(f_live, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return val, inside.to(X.dtype)


def epe(R, t, R_gt, t_gt, X, valid):
    """3-D end-point error per sample (metres): mean over valid X of |T X - T_gt X|."""
    d = torch.einsum("bij,bjhw->bihw", R - R_gt, X) + (t - t_gt).view(-1, 3, 1, 1)
    e = torch.sqrt((d * d).sum(1, keepdim=True) + 1e-12)
    return (e * valid).sum((1, 2, 3)) / valid.sum((1, 2, 3)).clamp(min=1)


class DeepICLK(nn.Module):
    def __init__(self, size="s16", iterations=20, lam=1e-6, channels=1):
        super().__init__()
        self.size, self.channels = size, channels
        levels = len(SIZES[size]["encoder"])
        self.encoder = Encoder(SIZES[size]["encoder"], channels)
        self.mest = MEstimator(SIZES[size]["mest"])
        self.levels, self.iterations, self.lam = levels, iterations, lam
        # The tilt prior (rad per axis; 0: none), as the C++ solver's TrackerOptions::
        # tilt_prior_rad: forward's `up` holds the answer's roll and pitch to the start's.
        self.tilt_sigma = 0.0

    def forward(self, ref_rgb, ref_depth, live_rgb, K, R0=None, t0=None, truth=None, return_weights=False,
                anchor_iterations=0, up=None):
        """ref_rgb, live_rgb: B x 3 x H x W (0..255); ref_depth: B x 1 x H x W (NaN: none);
        K: (fx, fy, cx, cy), each a B tensor; R0, t0: initial T_live_ref (identity if None);
        truth: (R_gt, t_gt) for the loss. Returns (R, t, per-level EPE list or None, weights).
        anchor_iterations > 0 (training only, with truth): each level also runs that many LM
        iterations started at the truth, its M-estimator's weights taken there, and
        self.anchor_losses holds each level's 3-D EPE after them: how far the level's learned
        cost moves a right answer, zero when its minimum is at the truth. up: B x 3, the world's
        up in the reference camera; with self.tilt_sigma > 0 the LM holds the answer's rotation
        about the two axes orthogonal to it to the start's (the C++ solver's tilt prior)."""
        B = ref_rgb.shape[0]
        dtype = ref_rgb.dtype
        fr = self.encoder(ref_rgb)
        fl = self.encoder(live_rgb)
        dp = depth_pyramid(ref_depth, self.levels)
        Ks = [K]
        for _ in range(1, self.levels):
            Ks.append(half(Ks[-1]))
        R = torch.eye(3, dtype=dtype).repeat(B, 1, 1) if R0 is None else R0
        R_init = R
        t = torch.zeros(B, 3, dtype=dtype) if t0 is None else t0
        X0 = points(dp[0][0], Ks[0])
        losses, weights = [], [None] * self.levels
        # The largest step (rad, or translation / median depth) per sample; the C++ solver
        # calls a step over 0.35 a divergence (TrackerOptions::max_step_rotation/translation).
        self.max_step = torch.zeros(B, dtype=dtype)
        w_prev = None
        self.anchor_losses = []
        for level in range(self.levels - 1, -1, -1):
            Kl = Ks[level]
            depth, valid = dp[level]
            multi = self.channels > 1  # each channel normalised on its own; Jacobians per channel
            f_ref = normalise(fr[level], valid)
            f_live = normalise(fl[level], torch.ones_like(valid))
            mask = usable_mask(valid)
            X = points(depth, Kl)
            if multi:
                J = torch.stack([jacobian(sobel(f_ref[:, c:c + 1]), X, Kl) * mask for c in range(self.channels)], 1)
            else:
                J = jacobian(sobel(f_ref), X, Kl) * mask
            abs_r = self._abs_residual(f_ref, f_live, X, R, t, Kl, mask)
            if multi:  # the M-estimator sees the residual's RMS over channels and the channel means
                m_ref, m_live = f_ref.mean(1, keepdim=True), f_live.mean(1, keepdim=True)
            else:
                m_ref, m_live = f_ref, f_live
            if w_prev is None:
                w_prev = torch.ones_like(m_ref)
            else:
                w_prev = F.interpolate(w_prev, size=f_ref.shape[-2:], mode="bilinear", align_corners=False)
            w_level_start = w_prev
            w = self.mest(abs_r, m_ref, m_live, w_prev)
            weights[level] = w
            w_prev = w
            Jf = J.flatten(-2)  # B x 6 x n, or B x C x 6 x n
            with torch.no_grad():  # the C++ solver's step bound is in units of the median depth
                med = torch.stack([d[m > 0].median() if (m > 0).any() else d.new_tensor(1.0)
                                   for d, m in zip(depth[:, 0], mask[:, 0])])
            R, t = self._lm(R, t, w * mask, Jf, f_ref, f_live, X, Kl, self.iterations, med,
                            up=up if self.tilt_sigma > 0 else None, R_init=R_init)
            if truth is not None:
                losses.append(epe(R, t, truth[0], truth[1], X0, dp[0][1]))
            if anchor_iterations > 0 and truth is not None:
                abs_a = self._abs_residual(f_ref, f_live, X, truth[0], truth[1], Kl, mask)
                w_a = self.mest(abs_a, m_ref, m_live, w_level_start)
                Ra, ta = self._lm(truth[0], truth[1], w_a * mask, Jf, f_ref, f_live, X, Kl, anchor_iterations)
                self.anchor_losses.append(epe(Ra, ta, truth[0], truth[1], X0, dp[0][1]))
        return R, t, losses, (weights if return_weights else None)

    def _abs_residual(self, f_ref, f_live, X, R, t, Kl, mask):
        """The M-estimator's residual input at pose (R, t): |r|, or with several channels their RMS;
        zero where the pixel is masked or leaves the image."""
        val, inside = warp_sample(f_live, X, R, t, Kl)
        if self.channels > 1:
            return torch.sqrt(((val - f_ref) ** 2).mean(1, keepdim=True) + 1e-12) * mask * inside
        return (val - f_ref).abs() * mask * inside

    def _image_noise(self, res, wi):
        """The C++ solver's image noise sigma^2 f at the level's first step (tracker.cpp's
        image_noise): the weighted mean square residual per channel and pixel, times the
        inflation ((1 + rho) / (1 - rho))^2 of the horizontal neighbours' correlation rho (clamped
        to [0, 0.9]) and, with several channels, Kish's 1 + (C - 1) rho_c of their correlation.
        res: B x C x h x w, wi: B x 1 x h x w. No gradient."""
        with torch.no_grad():
            res, wi = res.double(), wi.double()
            C = res.shape[1]
            cost = (wi * res * res).sum((1, 2, 3))
            wsum = C * wi.sum((1, 2, 3))
            base = cost / torch.clamp(wsum - 6, min=1.0)
            pair = ((wi[..., :-1] > 0) & (wi[..., 1:] > 0)).double()
            a, b = res[..., :-1] * pair, res[..., 1:] * pair
            sab, saa, sbb = (a * b).sum((1, 2, 3)), (a * a).sum((1, 2, 3)), (b * b).sum((1, 2, 3))
            rho = torch.where((saa > 0) & (sbb > 0), sab / torch.sqrt(saa * sbb + 1e-300), torch.zeros_like(sab))
            rho = rho.clamp(0.0, 0.9)
            f = ((1 + rho) / (1 - rho)) ** 2
            if C > 1:
                on = (wi > 0).double()
                r = res * on
                s = torch.einsum("bchw,bdhw->bcd", r, r)
                d = torch.sqrt(torch.diagonal(s, dim1=1, dim2=2))
                corr = s / torch.clamp(d.unsqueeze(-1) * d.unsqueeze(-2), min=1e-300)
                off = (corr.sum((1, 2)) - torch.diagonal(corr, dim1=1, dim2=2).sum(-1)) / (C * (C - 1))
                f = f * (1 + (C - 1) * off.clamp(0.0, 1.0))
            return f * base

    def _lm(self, R, t, Wm, Jf, f_ref, f_live, X, Kl, iterations, med=None, up=None, R_init=None):
        """`iterations` inverse-compositional LM steps from (R, t) at one level; with med (the
        level's median depth) the largest step is recorded in self.max_step; with up (B x 3) and
        self.tilt_sigma > 0, the tilt prior about R_init (forward's)."""
        multi = self.channels > 1
        dtype = R.dtype
        P = None
        for _ in range(iterations):
            val, inside = warp_sample(f_live, X, R, t, Kl)
            r = (val - f_ref).flatten(2)
            wi = (Wm * inside).flatten(2)
            if multi:
                wc = wi.unsqueeze(1)  # B x 1 x 1 x n
                H = torch.einsum("bcin,bcjn->bij", Jf * wc, Jf).double()
                g = torch.einsum("bcin,bcn->bi", Jf * wc, r).double()
            else:
                H = torch.einsum("bin,bjn->bij", Jf * wi, Jf).double()
                g = torch.einsum("bin,bn->bi", Jf * wi, r[:, 0]).double()
            A = H + self.lam * torch.diag_embed(torch.diagonal(H, dim1=1, dim2=2))
            A = A + 1e-12 * torch.eye(6, dtype=A.dtype)  # keeps solve defined when nothing is seen
            if up is not None:
                # 1/2 e^T P e on e = log(R_init^T R), P = noise (I - u u^T) / sigma^2; the step
                # R <- R exp(-delta) gives e - delta, so P joins A and P e joins g (tracker.cpp).
                if P is None:
                    u = (up / up.norm(dim=-1, keepdim=True)).double()
                    info = (torch.eye(3, dtype=torch.float64) - u.unsqueeze(-1) * u.unsqueeze(-2)) / self.tilt_sigma ** 2
                    P = self._image_noise(val - f_ref, Wm * inside).view(-1, 1, 1) * info
                e = so3_log(R_init.transpose(1, 2) @ R).double()
                A = A + F.pad(P, (0, 3, 0, 3))
                g = g + F.pad((P @ e.unsqueeze(-1)).squeeze(-1), (0, 3))
            delta = torch.linalg.solve(A, g.unsqueeze(-1)).squeeze(-1).to(dtype)
            R, t = compose_inverse_exp(R, t, delta)
            if med is not None:
                with torch.no_grad():
                    self.max_step = torch.maximum(self.max_step, torch.maximum(
                        delta[:, :3].norm(dim=1), delta[:, 3:].norm(dim=1) / med))
        return R, t


def quat_to_R(q):
    """q: B x 4 (w, x, y, z) -> B x 3 x 3."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1).view(-1, 3, 3)


def load_model(path, iterations=20, channels=None):
    """A model from a checkpoint (train_deep.py's .pt) or a weight file (export_deep.py's .tlw:
    its size from the '# terralign learned tracker, size X' line, its channels from the 'mean
    f0 IN G' line). `channels` overrides either: the same tensors, their outputs grouped
    otherwise. Returns the model and (size, channels, step or None)."""
    if path.endswith(".tlw"):
        import re
        import tlw
        arch, _ = tlw.architecture(path)
        size = re.search(r"^# terralign learned tracker, size (\w+)$", arch, re.M)
        mean = re.search(r"^mean f0 \S+(?: (\d+))?$", arch, re.M)
        if not size or not mean:
            raise ValueError(f"{path}: not a learned-tracker weight file (no size line or no 'mean f0')")
        k = channels or int(mean.group(1) or 1)
        model = DeepICLK(size.group(1), iterations=iterations, channels=k)
        model.load_state_dict({n: torch.from_numpy(v) for n, v in tlw.read(path).items()})
        return model, (size.group(1), k, None)
    ck = torch.load(path, map_location="cpu")
    k = channels or ck.get("channels", 1)
    model = DeepICLK(ck["size"], iterations=iterations, channels=k)
    model.load_state_dict(ck["model"])
    return model, (ck["size"], k, ck.get("step"))
