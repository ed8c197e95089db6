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


def _pour(c, rows, amount):
    """Fills the pixels of column `c` at `rows`, in order, up to 255 each, from `amount`;
    returns what is left."""
    for yy in rows:
        if amount <= 0:
            break
        put = min(max(255.0 - c[yy], 0.0), amount)
        c[yy] += put
        amount -= put
    return amount


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
            # Half down, then what found no room below goes up with the other half;
            # what finds no room above goes down again.
            down = _pour(c, range(y + 1, h), excess / 2)
            up = _pour(c, range(y - 1, -1, -1), excess / 2 + down)
            _pour(c, range(y + 1, h), up)
    return np.minimum(e, 255.0)
