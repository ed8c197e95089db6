"""Grey levels of a radiance image as a sensor that blooms vertically captures them, for
the benchmarks that measure noise on that scale (tools/bench-ab with NOISE=1,
tools/bench-paper-spp): negative radiance as 0 (the sensor's mean electrons), the
excess above 255 spilled along its column as `render::sensor::bloom_vertical` spills
charge (half down and half up, what finds no room going one way going the other), then
clipped at 255, so that the pixels a glint's excess fills are clipped as the image clips
them. A twin of the Rust function on purpose: it works on radiance scaled to grey levels,
without the sensor's shot noise, so that only the renderer's noise is measured.
"""
import numpy as np


def captured(g):
    """`g`: a 2-D array of grey levels (radiance times the exposure's scale)."""
    e = np.maximum(np.asarray(g, dtype=np.float64), 0.0)
    h, w = e.shape
    for x in range(w):
        c = e[:, x]
        for y in np.nonzero(c > 255.0)[0]:
            excess = c[y] - 255.0
            if excess <= 0.0:
                continue
            c[y] = 255.0
            up, down = excess / 2, excess / 2
            yy = y + 1
            while down > 0 and yy < h:
                put = min(max(255.0 - c[yy], 0.0), down)
                c[yy] += put
                down -= put
                yy += 1
            up += down
            yy = y
            while up > 0 and yy > 0:
                yy -= 1
                put = min(max(255.0 - c[yy], 0.0), up)
                c[yy] += put
                up -= put
            yy = y + 1
            while up > 0 and yy < h:
                put = min(max(255.0 - c[yy], 0.0), up)
                c[yy] += put
                up -= put
                yy += 1
    return np.minimum(e, 255.0)
