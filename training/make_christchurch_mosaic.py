#!/usr/bin/python3
"""Builds the Christchurch training map: the WHU-CD pairs of ../shared/data that are not the
evaluation tiles (data/christchurch: 000121, 000241), laid side by side in one strip per year.

  /usr/bin/python3 training/make_christchurch_mosaic.py OUT_DIR [--shared ../shared/data]

The six 512 x 512 LGPNet tiles (train 0-3, test 5 and 11) and the four 256 x 256 BiFA tiles
(as one 512 x 512 block of 2 x 2) make a strip of 7 blocks, 3584 x 512 pixels at 0.2 m/px
(717 x 102 m) in a local frame, for 2012 and for 2016. The blocks are different places: a
view across a seam sees two of them, which is still one flat textured plane in both years,
so the geometry the tracker learns from is exact. OUT_DIR gets christchurch_2012.png,
christchurch_2016.png (with .pgw world files) and christchurch_train.json for
`terralign dataset` (--split-fraction 0.3 holds the last two blocks back for validation).

Imagery: Land Information New Zealand (LINZ, Toitu Te Whenua), Christchurch aerial
photography, CC BY 4.0, via the WHU building change detection dataset.
"""
import argparse
import json
import os

from PIL import Image

GSD = 0.2  # m per pixel, as data/christchurch
BLOCK = 512


def blocks(shared):
    lg = os.path.join(shared, "whu_cd_christchurch_more_samples", "lgpnet_512")
    bf = os.path.join(shared, "whu_cd_christchurch_more_samples", "bifa_256")
    out = []
    for split, n in (("train", 0), ("train", 1), ("train", 2), ("train", 3), ("test", 5), ("test", 11)):
        out.append(tuple(os.path.join(lg, split, d, f"{n}.tif") for d in ("image1", "image2")))
    bifa = [(os.path.join(bf, "A", f"whu_A_{n}.png"), os.path.join(bf, "B", f"whu_B_{n}.png")) for n in (28, 123, 541, 635)]
    out.append(bifa)
    return out


def load(path, size):
    im = Image.open(path).convert("RGB")
    if im.size != (size, size):
        raise SystemExit(f"{path}: expected {size} x {size} pixels, found {im.size[0]} x {im.size[1]}")
    return im


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out")
    p.add_argument("--shared", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data"))
    a = p.parse_args()
    bl = blocks(a.shared)
    os.makedirs(a.out, exist_ok=True)
    for year, k in (("2012", 0), ("2016", 1)):
        strip = Image.new("RGB", (BLOCK * len(bl), BLOCK))
        for i, b in enumerate(bl):
            if isinstance(b, list):  # the BiFA tiles, 2 x 2
                for j, pair in enumerate(b):
                    strip.paste(load(pair[k], BLOCK // 2), (i * BLOCK + (j % 2) * BLOCK // 2, (j // 2) * BLOCK // 2))
            else:
                strip.paste(load(b[k], BLOCK), (i * BLOCK, 0))
        name = f"christchurch_{year}"
        tmp = os.path.join(a.out, name + ".tmp.png")
        strip.save(tmp)
        os.replace(tmp, os.path.join(a.out, name + ".png"))
        # World file: pixel size, rotation terms, the first pixel's centre; y grows north.
        with open(os.path.join(a.out, name + ".pgw"), "w") as f:
            f.write(f"{GSD}\n0\n0\n{-GSD}\n{GSD / 2}\n{BLOCK * GSD - GSD / 2}\n")
    m = {"name": "Christchurch WHU-CD training strip (LGPNet tiles train 0-3, test 5, 11; BiFA 28, 123, 541, 635), "
                 "2012 and 2016 (LINZ, CC BY 4.0), 0.2 m/px in a local frame: training only",
         "crs": "local", "dem": {"constant": 0.0},
         "layers": [{"name": "2012", "file": "christchurch_2012.png"}, {"name": "2016", "file": "christchurch_2016.png"}]}
    with open(os.path.join(a.out, "christchurch_train.json"), "w") as f:
        json.dump(m, f, indent=2)
        f.write("\n")
    print(f"{a.out}: {len(bl)} blocks, {BLOCK * len(bl)} x {BLOCK} px ({BLOCK * len(bl) * GSD:.0f} x {BLOCK * GSD:.0f} m)")


if __name__ == "__main__":
    main()
