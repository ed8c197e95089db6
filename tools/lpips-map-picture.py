#!/usr/bin/env python3
"""Two grey images and their LPIPS map side by side (`synosis metrics A B --lpips
--lpips-map MAP.exr`), each scaled by SCALE (default 1/3), titled; the map in a
black-red-yellow-white ramp from 0 to its 99.5th percentile (printed). Used for
docs/img/lpips-map.png (docs/metrics.md, "LPIPS"). Needs numpy, OpenEXR and Pillow.

Usage: tools/lpips-map-picture.py OUT.png A.png B.png MAP.exr TITLE_A TITLE_B [SCALE]
"""
import sys

import numpy as np
from PIL import Image, ImageDraw

from picture_row import load_exr, row


def ramp(t):
    """Black -> red -> yellow -> white over t in [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    r = np.clip(3 * t, 0, 1)
    g = np.clip(3 * t - 1, 0, 1)
    b = np.clip(3 * t - 2, 0, 1)
    return (np.stack([r, g, b], axis=-1) * 255).astype(np.uint8)


def titled(img, title):
    d = ImageDraw.Draw(img)
    d.rectangle([0, 0, 8 + 7 * len(title), 16], fill=(255, 255, 255))
    d.text((4, 2), title, fill=(0, 0, 0))
    return img


def main():
    if len(sys.argv) < 7:
        sys.exit(__doc__)
    out, a, b, m, ta, tb = sys.argv[1:7]
    scale = float(sys.argv[7]) if len(sys.argv) > 7 else 1 / 3
    mp = load_exr(m)
    top = float(np.percentile(mp, 99.5))
    print(f"map: mean {mp.mean():.4f}, 99.5th percentile {top:.4f}, max {mp.max():.4f}")
    size = (round(mp.shape[1] * scale), round(mp.shape[0] * scale))
    tiles = [
        titled(Image.open(a).convert("RGB").resize(size, Image.LANCZOS), ta),
        titled(Image.open(b).convert("RGB").resize(size, Image.LANCZOS), tb),
        titled(Image.fromarray(ramp(mp / top)).resize(size, Image.LANCZOS), f"LPIPS map, 0 to {top:.2f}"),
    ]
    row(tiles, 6).save(out)


if __name__ == "__main__":
    main()
