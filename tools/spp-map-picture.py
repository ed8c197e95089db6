#!/usr/bin/env python3
"""Picture of a dataset image beside its samples-per-pixel map (spp.png, written with
`[render] adaptive_radius`): the radiance scaled by EXPOSURE, gamma 1/2.2; the samples
from the fewest (dark blue) to the most (yellow); both enlarged 2x and labelled. Used
for docs/img/issue15-spp-map.png (docs/benchmarks/dataset.md, "Samples per pixel by the
pixel's own noise"). Needs numpy, OpenEXR and Pillow.

Usage: tools/spp-map-picture.py OUT.png IMAGE_DIR [--exposure 9.8] [--title TEXT]
"""
import argparse

import numpy as np
from PIL import Image, ImageDraw

from picture_row import load_exr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("image_dir", help="a dataset image's folder (radiance.exr, spp.png)")
    ap.add_argument("--exposure", type=float, default=9.8)
    ap.add_argument("--title", default="image")
    a = ap.parse_args()
    radiance = load_exr(a.image_dir + "/radiance.exr")
    h, w = radiance.shape
    v = np.clip(radiance * a.exposure, 0, 1) ** (1 / 2.2)
    image = Image.fromarray((v * 255 + 0.5).astype(np.uint8)).convert("RGB")
    spp = np.array(Image.open(a.image_dir + "/spp.png")).astype(np.float64)
    lo, hi = spp.min(), spp.max()
    t = np.clip((spp - lo) / max(hi - lo, 1.0), 0, 1)
    ramp = np.stack([t**0.8 * 255, (0.15 + 0.85 * t) * 255 * t**0.3, (1 - t) * 120 + 20], -1)
    samples = Image.fromarray(ramp.astype(np.uint8))
    panel_w, top = 2 * w, 22
    out = Image.new("RGB", (2 * panel_w + 10, 2 * h + top), (255, 255, 255))
    labels = [
        f"{a.title} (mean {spp.mean():.1f} spp)",
        f"samples per pixel: {lo:.0f} (dark) to {hi:.0f} (bright)",
    ]
    for k, (im, label) in enumerate(zip([image, samples], labels)):
        out.paste(im.resize((panel_w, 2 * h), Image.NEAREST), (k * (panel_w + 10), top))
        ImageDraw.Draw(out).text((k * (panel_w + 10) + 4, 5), label, fill=(0, 0, 0))
    out.save(a.out)
    print(f"wrote {a.out} ({out.size[0]} x {out.size[1]})")


if __name__ == "__main__":
    main()
