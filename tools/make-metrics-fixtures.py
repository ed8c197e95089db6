#!/usr/bin/env python3
"""Makes the fixtures of tests/metrics.rs: small 8- and 16-bit grayscale PNG pairs and
masks under tests/fixtures/metrics/, and expected.json with the metric values computed
by independent implementations:

- SSIM: skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=255) on float64 images in 8-bit units
  (16-bit codes / 257). Unmasked: skimage's own mean (border of 5 px cropped).
  Masked: the full SSIM map (full=True) averaged over the mask pixels.
- hist_wd: scipy.stats.wasserstein_distance of the (masked) pixel values.
- mae: numpy mean of |a - b| over the (masked) pixels.

Run: pip install scikit-image scipy numpy imageio; python3 tools/make-metrics-fixtures.py
Deterministic (fixed seed).
"""
import json
import os

import imageio.v3 as iio
import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.stats import wasserstein_distance
from skimage.metrics import structural_similarity

OUT = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "metrics")
W, H = 64, 48
rng = np.random.default_rng(20240607)
yy, xx = np.mgrid[0:H, 0:W]


def smooth_noise(scale, sigma):
    return gaussian_filter(rng.normal(0.0, scale, (H, W)), sigma)


def to8(x):
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def to16(x):
    return np.clip(np.rint(x), 0, 65535).astype(np.uint16)


def units(arr):
    """Intensities in 8-bit units as float64, the convention of synosis::metrics."""
    if arr.dtype == np.uint16:
        return arr.astype(np.float64) / 257.0
    return arr.astype(np.float64)


images = {
    # textured 8-bit pair: gradient + smooth noise, second is a shifted/noisier variant
    "tex_a.png": to8(60 + 1.5 * xx + 40 * smooth_noise(3.0, 1.2)),
    "tex_b.png": to8(70 + 1.4 * xx + 40 * smooth_noise(3.0, 1.2) + rng.normal(0, 8, (H, W))),
    # milling-like stripes against a phase-shifted, rescaled copy with noise
    "stripes_a.png": to8(128 + 90 * np.sin(xx * 0.7 + 0.2 * yy)),
    "stripes_b.png": to8(110 + 70 * np.sin(xx * 0.7 + 0.2 * yy + 0.9) + rng.normal(0, 5, (H, W))),
    # nearly flat images: variance far below C2, the hard case for f32 moments
    "flat_a.png": to8(200 + rng.normal(0, 1.0, (H, W))),
    "flat_b.png": to8(198 + rng.normal(0, 1.0, (H, W))),
    # 16-bit pair, full range
    "deep_a.png": to16(30000 + 300 * xx + 6000 * smooth_noise(3.0, 1.5)),
    "deep_b.png": to16(28000 + 320 * xx + 6000 * smooth_noise(3.0, 1.5) + rng.normal(0, 900, (H, W))),
}
masks = {
    "mask_ellipse.png": (((xx - 30) / 22.0) ** 2 + ((yy - 22) / 15.0) ** 2 <= 1.0),
    # touches the image border, so reflected neighbours enter the masked SSIM
    "mask_corner.png": (xx < 25) & (yy < 20) | ((xx + yy) % 7 == 0),
}

cases = [
    ("tex_a.png", "tex_b.png", None),
    ("tex_a.png", "tex_b.png", "mask_ellipse.png"),
    ("stripes_a.png", "stripes_b.png", None),
    ("stripes_a.png", "stripes_b.png", "mask_corner.png"),
    ("flat_a.png", "flat_b.png", None),
    ("flat_a.png", "flat_b.png", "mask_ellipse.png"),
    ("deep_a.png", "deep_b.png", None),
    ("deep_a.png", "deep_b.png", "mask_corner.png"),
    # 8-bit against 16-bit: both read in 8-bit units
    ("tex_a.png", "deep_b.png", "mask_ellipse.png"),
]


def main():
    os.makedirs(OUT, exist_ok=True)
    for name, arr in images.items():
        iio.imwrite(os.path.join(OUT, name), arr)
    for name, m in masks.items():
        iio.imwrite(os.path.join(OUT, name), (m * 255).astype(np.uint8))
    expected = []
    for a_name, b_name, m_name in cases:
        # Read back what was written, so the expectations describe the files.
        a = units(iio.imread(os.path.join(OUT, a_name)))
        b = units(iio.imread(os.path.join(OUT, b_name)))
        kw = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255.0)
        if m_name is None:
            ssim = structural_similarity(a, b, **kw)
            sel = np.ones_like(a, dtype=bool)
        else:
            sel = iio.imread(os.path.join(OUT, m_name)) != 0
            _, smap = structural_similarity(a, b, full=True, **kw)
            ssim = float(smap[sel].mean())
        expected.append(
            dict(
                a=a_name,
                b=b_name,
                mask=m_name,
                pixels=int(sel.sum()),
                hist_wd=float(wasserstein_distance(a[sel], b[sel])),
                mae=float(np.mean(np.abs(a - b)[sel])),
                ssim=float(ssim),
            )
        )
    with open(os.path.join(OUT, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1)
        f.write("\n")
    print(json.dumps(expected, indent=1))


if __name__ == "__main__":
    main()
