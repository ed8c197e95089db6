#!/usr/bin/env python3
"""Side-by-side picture of renders (one-channel EXRs of the same size): each scaled by
EXPOSURE, gamma 1/2.2, cropped to BOX (x0 y0 x1 y1), enlarged 2x, labelled, in a row.
Used for docs/img/issue15-vs-mitsuba-milled.png (commands in docs/benchmarks/rendering.md,
"A look at equal time"). Needs numpy, OpenEXR and Pillow.

Usage: tools/vs-mitsuba-picture.py OUT.png --exposure 12 --box 53 38 253 218 \
       "LABEL=render.exr" ["LABEL=render.exr" ...]
"""
import argparse

import numpy as np
from PIL import Image, ImageDraw

from picture_row import load_exr, row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("panels", nargs="+", help="LABEL=FILE.exr")
    ap.add_argument("--exposure", type=float, default=12.0)
    ap.add_argument("--box", type=int, nargs=4, default=None)
    a = ap.parse_args()
    imgs = []
    for panel in a.panels:
        label, path = panel.split("=", 1)
        v = np.clip(load_exr(path) * a.exposure, 0, 1) ** (1 / 2.2)
        im = Image.fromarray((v * 255 + 0.5).astype(np.uint8)).convert("RGB")
        if a.box:
            im = im.crop(tuple(a.box))
        im = im.resize((2 * im.width, 2 * im.height), Image.NEAREST)
        d = ImageDraw.Draw(im)
        d.rectangle((0, 0, im.width, 16), fill=(0, 0, 0))
        d.text((4, 2), label, fill=(255, 255, 255))
        imgs.append(im)
    out = row(imgs, 6)
    out.save(a.out, optimize=True)
    print(f"wrote {a.out} ({out.width} x {out.height})")


if __name__ == "__main__":
    main()
