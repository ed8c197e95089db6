#!/usr/bin/env python3
"""The render_convergence scene in Mitsuba 3, for side-by-side speed and agreement.

Reads the export of `cargo run --example render_convergence -- --export-mitsuba DIR`
(object*.ply, table.ply, light.ply: flat triangles, our winding; scene.json: camera,
materials, the object's parts; slopes-B-x/y.exr: the object's slope maps), builds the
same scene (rough GGX conductor with the same complex IOR and alpha, visible-normal
sampling, separable Smith G as ours; the slope-mapped parts wrapped in Mitsuba's
`normalmap` with the map's slopes as a raw bilinear, repeating normal map at the PLY's
per-vertex u, v; black diffuse table; the tessellated torus as an area emitter with the
same radiance; pinhole camera with the same pose and horizontal field of view; box pixel
filter), renders it at a list of spp, times each, and computes the RMSE against its own
high-spp reference and the mean difference against our reference image. Mitsuba's
roughconductor has no multiple-scattering compensation, so ours must be rendered with
--no-compensation for the comparison. Known differences on slope-mapped faces: our
shading normals that face away from the viewer are bent towards it (docs/rendering.md),
Mitsuba's normalmap drops such samples; our slopes are clamped to 85 degrees.

Usage: tools/mitsuba_scene.py DIR --ours OURS_REFERENCE.exr --spp 1,4,16 --ref-spp 4096
       --out OUT_STEM [--variant llvm_ad_rgb] [--ref-halves]
Writes OUT_STEM.md (table) and OUT_STEM.json (numbers) and prints the table.
"""
import argparse
import json
import os
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--ours", required=True, help="our high-spp reference (EXR, channel Y)")
    ap.add_argument("--spp", default="1,4,16,64,256,1024")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--save-images", action="store_true",
                    help="write each row's image as OUT_STEM-SPP.exr (channel Y)")
    ap.add_argument("--ref-halves", action="store_true",
                    help="reference = two halves of --ref-spp with independent seeds; their difference "
                         "estimates its own noise, taken out of each row's RMSE (rmse_net)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    import mitsuba as mi

    try:
        mi.set_variant(a.variant)
    except Exception as e:  # no libllvm: say so and fall back
        print(f"variant {a.variant} unavailable ({e}); using scalar_rgb")
        a.variant = "scalar_rgb"
        mi.set_variant(a.variant)

    with open(os.path.join(a.dir, "scene.json")) as f:
        s = json.load(f)
    eye = s["eye"]
    target = [eye[i] + s["forward"][i] for i in range(3)]
    ply = lambda n: os.path.join(a.dir, n + ".ply")

    conductor = {
        "type": "roughconductor",
        "distribution": "ggx",
        "alpha": float(s["alpha"]),
        "eta": float(s["ior_n"]),
        "k": float(s["ior_k"]),
        "sample_visible": True,
    }
    # The object's parts: triangles without a slope map, and per map and handedness of
    # the triangles' frames those with one (their per-vertex u, v in the PLY). Exports
    # from before slope maps have one part, object.ply.
    parts = s.get("object_parts", [{"ply": "object.ply", "map": None}])
    slopes = {}

    def normal_map(b, hand):
        # Our shading normal is normalize(n - dh/dx map_x + dh/dy map_up); Mitsuba's
        # normalmap reads (2 rgb - 1) in the frame (s = map x, t = cross(n, s) =
        # hand * map up, n), normalised: rgb = ((1 - dh/dx) / 2, (1 + hand dh/dy) / 2, 1)
        # is that normal, and bilinear filtering of rgb is bilinear filtering of the
        # slopes, as ours. Raw float texels (no sRGB, no clamping).
        if b not in slopes:
            slopes[b] = [np.array(mi.Bitmap(os.path.join(a.dir, f"slopes-{b}-{c}.exr")), dtype=np.float32)
                         .reshape(s["slope_maps"][b]["height"], s["slope_maps"][b]["width"]) for c in "xy"]
        sx, sy = slopes[b]
        rgb = np.stack([(1 - sx) / 2, (1 + hand * sy) / 2, np.ones_like(sx)], axis=-1).astype(np.float32)
        return {"type": "bitmap", "bitmap": mi.Bitmap(rgb), "raw": True,
                "filter_type": "bilinear", "wrap_mode": "repeat"}

    objects = {}
    for i, p in enumerate(parts):
        bsdf = conductor if p["map"] is None else {
            "type": "normalmap", "normalmap": normal_map(p["map"], p["handedness"]), "bsdf": conductor}
        objects[f"object{i}"] = {"type": "ply", "filename": os.path.join(a.dir, p["ply"]),
                                 "face_normals": True, "bsdf": bsdf}

    def scene(spp, seed):
        return mi.load_dict({
            **objects,
            "type": "scene",
            # Mitsuba's max_depth counts the camera segment: our max_bounces + 1.
            "integrator": {"type": "path", "max_depth": int(s["max_bounces"]) + 1},
            "sensor": {
                "type": "perspective",
                "fov": float(s["fov_x_deg"]),
                "fov_axis": "x",
                "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=target, up=s["up"]),
                "film": {
                    "type": "hdrfilm",
                    "width": int(s["width"]),
                    "height": int(s["height"]),
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            },
            "table": {
                "type": "ply",
                "filename": ply("table"),
                "face_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [s["table_albedo"]] * 3}},
            },
            "light": {
                "type": "ply",
                "filename": ply("light"),
                "face_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0] * 3}},
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [s["radiance"]] * 3}},
            },
        })

    def render(spp, seed):
        sc = scene(spp, seed)
        t = time.perf_counter()
        img = mi.render(sc, spp=spp, seed=seed)
        arr = np.array(img, dtype=np.float64)
        secs = time.perf_counter() - t
        return arr[:, :, :3].mean(axis=2), secs

    render(1, 99)  # warm-up: the llvm variant compiles kernels on first use
    ref_var = None
    if a.ref_halves:
        r1, s1 = render(a.ref_spp // 2, 12345)
        r2, s2 = render(a.ref_spp // 2, 54321)
        ref, ref_secs = (r1 + r2) / 2, s1 + s2
        ref_var = float(np.mean((r1 - r2) ** 2) / 4)
    else:
        ref, ref_secs = render(a.ref_spp, 12345)
    ours = np.array(mi.Bitmap(a.ours), dtype=np.float64)
    ours = ours.reshape(ref.shape) if ours.size == ref.size else ours[..., 0]
    diff = ref - ours
    mean_ours, mean_mts = ours.mean(), ref.mean()
    # A mirrored camera would agree far better with a flipped image: report both.
    flip = np.sqrt(np.mean((ref[:, ::-1] - ours) ** 2))
    rows = []
    for spp in [int(x) for x in a.spp.split(",")]:
        img, secs = render(spp, 7)
        if a.save_images:
            mi.Bitmap(img.astype(np.float32)).write(f"{a.out}-{spp}.exr")
        mse = float(np.mean((img - ref) ** 2))
        rows.append({"spp": spp, "secs": secs, "rmse": float(np.sqrt(mse)),
                     "rmse_net": None if ref_var is None else float(np.sqrt(max(mse - ref_var, 0.0))),
                     "load": os.getloadavg()[0]})
        print(f"mitsuba {spp:5d} spp: {secs:8.2f} s RMSE {rows[-1]['rmse']:.3e}", flush=True)
    res = {
        "variant": a.variant,
        "mitsuba": mi.__version__,
        "ref_spp": a.ref_spp,
        "ref_secs": ref_secs,
        "ref_var": ref_var,
        "mean_ours": float(mean_ours),
        "mean_mitsuba": float(mean_mts),
        "mean_rel_diff": float((mean_mts - mean_ours) / mean_ours),
        "mean_abs_diff": float(np.abs(diff).mean()),
        "rmse_ours_vs_mitsuba": float(np.sqrt(np.mean(diff ** 2))),
        "rmse_vs_flipped": float(flip),
        "rows": rows,
    }
    with open(a.out + ".json", "w") as f:
        json.dump(res, f, indent=1)
    halves = "" if ref_var is None else \
        f" (two halves; its own noise {np.sqrt(ref_var):.3e} RMSE, taken out of the net RMSE)"
    md = [f"Mitsuba {mi.__version__} `{a.variant}`, path tracer, independent sampler; reference "
          f"{a.ref_spp} spp in {ref_secs:.1f} s{halves}.\n"]
    if ref_var is None:
        md += ["| spp | seconds (wall) | RMSE vs Mitsuba reference | load (1 min) |", "|---|---|---|---|"]
        md += [f"| {r['spp']} | {r['secs']:.2f} | {r['rmse']:.3e} | {r['load']:.2f} |" for r in rows]
    else:
        md += ["| spp | seconds (wall) | RMSE vs Mitsuba reference | net RMSE | load (1 min) |", "|---|---|---|---|---|"]
        md += [f"| {r['spp']} | {r['secs']:.2f} | {r['rmse']:.3e} | {r['rmse_net']:.3e} | {r['load']:.2f} |" for r in rows]
    md.append("")
    md.append(f"High-spp images, ours vs Mitsuba: mean radiance {mean_ours:.5f} vs {mean_mts:.5f} "
              f"({100 * res['mean_rel_diff']:+.2f} %), mean |difference| {res['mean_abs_diff']:.2e}, "
              f"RMSE {res['rmse_ours_vs_mitsuba']:.2e} (against the mirrored image: {flip:.2e}).")
    with open(a.out + ".md", "w") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
