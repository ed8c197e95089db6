#!/usr/bin/env python3
"""Side-by-side picture of renders (one-channel EXRs of the same size): each scaled by
EXPOSURE, gamma 1/2.2, cropped to BOX (x0 y0 x1 y1), enlarged 2x, labelled, in a row.
Used for docs/img/issue15-vs-mitsuba-milled.png (commands in docs/benchmarks/rendering.md,
"A look at equal time"). Needs numpy, OpenEXR and Pillow.

Usage: tools/vs-mitsuba-picture.py OUT.png --exposure 12 --box 53 38 253 218 \
       "LABEL=render.exr" ["LABEL=render.exr" ...]
"""
import argparse

import Imath
import numpy as np
import OpenEXR
from PIL import Image, ImageDraw


def load(path):
    f = OpenEXR.InputFile(path)
    dw = f.header()["dataWindow"]
    w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
    channels = f.header()["channels"]
    ch = "Y" if "Y" in channels else ("R" if "R" in channels else next(iter(channels)))
    return np.frombuffer(f.channel(ch, Imath.PixelType(Imath.PixelType.FLOAT)), np.float32).reshape(h, w)


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
        v = np.clip(load(path) * a.exposure, 0, 1) ** (1 / 2.2)
        im = Image.fromarray((v * 255 + 0.5).astype(np.uint8)).convert("RGB")
        if a.box:
            im = im.crop(tuple(a.box))
        im = im.resize((2 * im.width, 2 * im.height), Image.NEAREST)
        d = ImageDraw.Draw(im)
        d.rectangle((0, 0, im.width, 16), fill=(0, 0, 0))
        d.text((4, 2), label, fill=(255, 255, 255))
        imgs.append(im)
    out = Image.new("RGB", (sum(i.width for i in imgs) + 6 * (len(imgs) - 1), imgs[0].height), (255, 255, 255))
    x = 0
    for i in imgs:
        out.paste(i, (x, 0))
        x += i.width + 6
    out.save(a.out, optimize=True)
    print(f"wrote {a.out} ({out.width} x {out.height})")


if __name__ == "__main__":
    main()
