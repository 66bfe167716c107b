"""Lv et al.'s encoder (ConvRGBD2 / FeaturePyramid) and M-estimator (MultiScale2w), re-expressed
from the description in DESIGN.md and the checkpoint's state_dict names (their code is not
copied). Used offline only: to write parity vectors and to convert weights.

Encoder: four levels; each level is three conv blocks (3x3, stride 1, padding = dilation,
no bias, BatchNorm, ELU) with dilations 1, 2, 2; channels 8->16->32->32, 32->32->64->64,
64->64->96->96, 96->96->128->128; average pooling by 2 between levels on the previous level's
features. Each level's output is also averaged over channels to one channel.
M-estimator: conv blocks 4->16 (dilation 1), 16->32 (2), 32->64 (4), 64->1 (1), each conv, BN,
ELU, then a sigmoid; input |r|, f_ref, f_live and the previous level's weight.
"""
import torch
import torch.nn as nn
import torch.nn.functional as F

RGB_MEAN = (0.4914, 0.4822, 0.4465)
RGB_STD = (0.2023, 0.1994, 0.2010)


def conv_block(cin, cout, dilation):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, 1, padding=dilation, dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout), nn.ELU(inplace=False))


class Encoder(nn.Module):
    WIDTHS = ((8, 16, 32, 32), (32, 32, 64, 64), (64, 64, 96, 96), (96, 96, 128, 128))

    def __init__(self):
        super().__init__()
        for level, (a, b, c, d) in enumerate(self.WIDTHS):
            setattr(self, f"net{level}", nn.Sequential(conv_block(a, b, 1), conv_block(b, c, 2), conv_block(c, d, 2)))

    def forward(self, x):
        feats = []
        for level in range(4):
            if level > 0:
                x = F.avg_pool2d(x, 2)
            x = getattr(self, f"net{level}")(x)
            feats.append(x)
        return feats


class MEstimator(nn.Module):
    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(conv_block(4, 16, 1), conv_block(16, 32, 2), conv_block(32, 64, 4),
                                 conv_block(64, 1, 1), nn.Sigmoid())

    def forward(self, abs_r, f_ref, f_live, w_prev):
        return self.net(torch.cat((abs_r, f_ref, f_live, w_prev), dim=1))


def load_lv19(path):
    """The encoder and M-estimator of the published checkpoint, in eval mode."""
    sd = torch.load(path, map_location="cpu")["state_dict"]
    enc, mest = Encoder(), MEstimator()
    enc.load_state_dict({k[len("encoder."):]: v for k, v in sd.items() if k.startswith("encoder.")})
    mest.load_state_dict({k[len("mEst_func."):]: v for k, v in sd.items() if k.startswith("mEst_func.")})
    return enc.eval(), mest.eval()


def normalise_rgb(rgb):
    """rgb: float tensor N x 3 x H x W in 0..255."""
    mean = torch.tensor(RGB_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(RGB_STD).view(1, 3, 1, 1)
    return (rgb / 255.0 - mean) / std


def inverse_depth(depth):
    """Metric depth (0 or NaN: none) -> inverse depth, 0 where none."""
    valid = torch.isfinite(depth) & (depth > 0)
    return torch.where(valid, 1.0 / torch.where(valid, depth, torch.ones_like(depth)), torch.zeros_like(depth))
