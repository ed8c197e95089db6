#!/usr/bin/env python3
"""Dataset images of one crop side by side, the last one the reference: each radiance in
grey levels at the reference's exposure (the brightest 5 % of its inspected faces'
pixels at 255, faces.png != 0, as tools/bench-ab compares), clipped to [0, 255], enlarged
2x and titled; prints each image's RMS difference from the reference in those clipped
grey levels. Used for docs/img/issue15-split-paths.png (docs/benchmarks/dataset.md,
"Split paths at the first hit"). Needs numpy, OpenEXR and Pillow.

Usage: tools/side-by-side-picture.py OUT.png DIR:TITLE [DIR:TITLE ...] REF_DIR:TITLE
(DIR: a dataset image's folder, with radiance.exr and faces.png)
"""
import sys

import numpy as np
from PIL import Image, ImageDraw

from picture_row import load_exr, row


def radiance(folder):
    return load_exr(folder + "/radiance.exr")


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    out, items = sys.argv[1], [a.split(":", 1) for a in sys.argv[2:]]
    if any(len(i) != 2 for i in items):
        sys.exit("each image is DIR:TITLE")
    ref_dir = items[-1][0]
    ref = radiance(ref_dir)
    faces = np.array(Image.open(ref_dir + "/faces.png"))
    faces = faces if faces.ndim == 2 else faces[..., 0]
    scale = 255.0 / np.percentile(ref[faces != 0], 95)
    grey = lambda a: np.clip(a * scale, 0, 255)
    tiles = []
    for folder, title in items:
        g = grey(radiance(folder))
        if folder != ref_dir:
            rms = float(np.sqrt(np.mean((g - grey(ref)) ** 2)))
            print(f"{title}: {rms:.2f} grey levels RMS from the reference")
        im = Image.fromarray((g + 0.5).astype(np.uint8)).convert("RGB")
        im = im.resize((im.width * 2, im.height * 2), Image.NEAREST)
        tile = Image.new("RGB", (im.width, im.height + 22), (255, 255, 255))
        tile.paste(im, (0, 22))
        ImageDraw.Draw(tile).text((6, 5), title, fill=(0, 0, 0))
        tiles.append(tile)
    row(tiles, 8).save(out, optimize=True)


if __name__ == "__main__":
    main()
