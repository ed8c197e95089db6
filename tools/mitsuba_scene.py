#!/usr/bin/env python3
"""The render_convergence scene in Mitsuba 3, for side-by-side speed and agreement.

Reads the export of `cargo run --example render_convergence -- --export-mitsuba DIR`
(object.ply, table.ply, light.ply: flat triangles, our winding; scene.json: camera and
materials), builds the same scene (rough GGX conductor with the same complex IOR and
alpha, visible-normal sampling, separable Smith G as ours; black diffuse table; the
tessellated torus as an area emitter with the same radiance; pinhole camera with the same
pose and horizontal field of view; box pixel filter), renders it at a list of spp, times
each, and computes the RMSE against its own high-spp reference and the mean difference
against our reference image. Mitsuba's roughconductor has no multiple-scattering
compensation, so ours must be rendered with --no-compensation for the comparison.

Usage: tools/mitsuba_scene.py DIR --ours OURS_REFERENCE.exr --spp 1,4,16 --ref-spp 4096
       --out OUT_STEM [--variant llvm_ad_rgb]
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

    def scene(spp, seed):
        return mi.load_dict({
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
            "object": {
                "type": "ply",
                "filename": ply("object"),
                "face_normals": True,
                "bsdf": {
                    "type": "roughconductor",
                    "distribution": "ggx",
                    "alpha": float(s["alpha"]),
                    "eta": float(s["ior_n"]),
                    "k": float(s["ior_k"]),
                    "sample_visible": True,
                },
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
        rows.append({"spp": spp, "secs": secs, "rmse": float(np.sqrt(np.mean((img - ref) ** 2))),
                     "load": os.getloadavg()[0]})
        print(f"mitsuba {spp:5d} spp: {secs:8.2f} s RMSE {rows[-1]['rmse']:.3e}", flush=True)
    res = {
        "variant": a.variant,
        "mitsuba": mi.__version__,
        "ref_spp": a.ref_spp,
        "ref_secs": ref_secs,
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
    md = [f"Mitsuba {mi.__version__} `{a.variant}`, path tracer, independent sampler; reference "
          f"{a.ref_spp} spp in {ref_secs:.1f} s.\n",
          "| spp | seconds (wall) | RMSE vs Mitsuba reference | load (1 min) |", "|---|---|---|---|"]
    md += [f"| {r['spp']} | {r['secs']:.2f} | {r['rmse']:.3e} | {r['load']:.2f} |" for r in rows]
    md.append("")
    md.append(f"High-spp images, ours vs Mitsuba: mean radiance {mean_ours:.5f} vs {mean_mts:.5f} "
              f"({100 * res['mean_rel_diff']:+.2f} %), mean |difference| {res['mean_abs_diff']:.2e}, "
              f"RMSE {res['rmse_ours_vs_mitsuba']:.2e} (against the mirrored image: {flip:.2e}).")
    with open(a.out + ".md", "w") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
