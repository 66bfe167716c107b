#!/usr/bin/python3
"""The README's overlay figure: one pose of a `terralign eval --json J --overlays D` run, its
four overlays (prior, classic:20, nn:20, truth) in a labelled 2 x 2 montage at half size.

  /usr/bin/python3 scripts/overlay_figure.py out/demo/eval_2009_2020.json \
      out/demo/overlays_2009_2020 5 docs/overlay_2009_2020.png

Needs Debian's python3-pil. Each label carries that method's 2-D EPE from the JSON and
"(failed)" where the method reported no convergence (the prior returned).
"""
import json
import os
import sys

from PIL import Image, ImageDraw


def main():
    if len(sys.argv) != 5:
        raise SystemExit(__doc__)
    eval_json, overlays, index, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    methods = json.load(open(eval_json))["methods"]
    panels = [("init", "prior (init)"), ("classic:20", "classic:20"), ("nn:20", "nn:20"), ("truth", "truth")]
    tiles = []
    for key, label in panels:
        path = os.path.join(overlays, f"{index}_{key.replace(':', '_')}.png")
        if not os.path.exists(path):
            raise SystemExit(f"{path}: no such overlay (was eval run with --overlays and method {key}?)")
        im = Image.open(path).convert("RGB")
        im = im.resize((im.width // 2, im.height // 2), Image.LANCZOS)
        if key != "truth":
            s = methods[key]["samples"][index]
            label += f": {s['epe_px']:.1f} px" + ("" if s["converged"] or key == "init" else " (failed)")
        tiles.append((im, label))
    w, h, bar, gap = tiles[0][0].width, tiles[0][0].height, 18, 6
    fig = Image.new("RGB", (2 * w + gap, 2 * (h + bar)), "white")
    draw = ImageDraw.Draw(fig)
    for k, (im, label) in enumerate(tiles):
        x, y = (k % 2) * (w + gap), (k // 2) * (h + bar)
        draw.text((x + 4, y + 3), label, fill="black")
        fig.paste(im, (x, y + bar))
    tmp = out + ".tmp.png"
    fig.save(tmp)
    os.replace(tmp, out)
    print(f"{out}: pose {index}, {' / '.join(label for _, label in tiles)}")


if __name__ == "__main__":
    main()
