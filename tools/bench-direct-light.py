#!/usr/bin/env python3
"""Pixel variance of one direct-light estimator over seeds (issue 15).

Renders SCENE SEEDS times (seeds 1..SEEDS, `[render] seed = 1` replaced) with
`[render] direct_light = DIRECT` at SPP samples and W x H, and prints the image mean, the
mean over pixels of the per-pixel variance across seeds, the share of pixels below zero
and the wall time per render. Needs numpy and OpenEXR (as tools/bench-lean).

Usage: tools/bench-direct-light.py BIN SCENE DIRECT SEEDS SPP W H
e.g.   tools/bench-direct-light.py target/release/synosis scenes/demo.toml analytic 6 16 153 128
"""
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import OpenEXR

binp, scene, direct, seeds, spp, w, h = sys.argv[1:8]
src = open(scene).read()
imgs = []
t0 = time.time()
for s in range(1, int(seeds) + 1):
    text = src.replace("seed = 1", f"seed = {s}")
    text = text.replace("[render]", f'[render]\ndirect_light = "{direct}"', 1)
    out = tempfile.mkdtemp()
    # Beside the scene, so that its relative paths still resolve.
    sc = os.path.join(os.path.dirname(os.path.abspath(scene)), f".bench-direct-{os.getpid()}.toml")
    open(sc, "w").write(text)
    try:
        r = subprocess.run([binp, "render", sc, "--out", out, "--spp", spp, "--width", w,
                            "--height", h], capture_output=True, text=True)
    finally:
        os.remove(sc)
    if r.returncode:
        sys.exit(r.stderr)
    a = np.array(next(iter(OpenEXR.File(os.path.join(out, "radiance.exr")).channels().values())).pixels,
                 dtype=np.float64)
    imgs.append(a[..., 0] if a.ndim == 3 else a)
x = np.stack(imgs)
print(f"{direct}: mean {x.mean():.6g}  mean pixel variance {x.var(0, ddof=1).mean():.4g}  "
      f"below zero {np.mean(x < 0) * 100:.3f} %  wall per render {(time.time() - t0) / len(imgs):.1f} s")
