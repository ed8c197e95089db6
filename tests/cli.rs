//! End-to-end tests of the `synosis` binary: exit codes, files written, and messages
//! (results on stdout, diagnostics on stderr, each error once, naming the user's input).
//! The GPU cases run on lavapipe with validation, at tiny sizes.

use std::path::Path;
use std::process::{Command, Output};

fn synosis(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args(args)
        .current_dir(dir)
        .env("SYNOSIS_VALIDATION", "1")
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX")
        .env_remove("SYNOSIS_SHARD_COUNT")
        .env_remove("SYNOSIS_ACCEL")
        .output()
        .unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Writes scene file `name` (`toml`) into `dir`, renders it into `out` there, asserts
/// that the render succeeded and returns its stderr.
fn render_scene(dir: &Path, name: &str, toml: &str, out: &str) -> String {
    std::fs::write(dir.join(name), toml).unwrap();
    let o = synosis(&["render", name, "--out", out], dir);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    err
}

/// Exit code 1, nothing on stdout, one `error:` line on stderr that contains each of `want`.
fn assert_fails(o: &Output, want: &[&str]) -> String {
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    assert_eq!(o.status.code(), Some(1), "stdout {out}\nstderr {err}");
    assert!(out.is_empty(), "stdout must stay empty on failure: {out}");
    assert_eq!(err.matches("error:").count(), 1, "{err}");
    for w in want {
        assert!(err.contains(w), "stderr {err:?} does not contain {w:?}");
    }
    err
}

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The smoke job cut to one 32 x 24 image at 1 spp.
fn tiny_job(dir: &Path) -> std::path::PathBuf {
    let text = std::fs::read_to_string(Path::new(ROOT).join("scenes/smoke-dataset.toml"))
        .unwrap()
        .replace("views = [\"A0\", \"C20\"]", "views = [\"A0\"]")
        .replace("width = 64", "width = 32")
        .replace("height = 48", "height = 24")
        .replace("spp = 4", "spp = 1")
        .replace("defective = 2", "defective = 1")
        .replace("defect_free = 2", "defect_free = 0")
        .replace("sets = 2", "sets = 1")
        .replace(
            "spec = \"defects-smoke.toml\"",
            &format!("spec = \"{ROOT}/scenes/defects-smoke.toml\""),
        );
    // One finish only: cut the second [[finish]] table.
    let a = text.find("[[finish]]\nname = \"parallel").unwrap();
    let b = text[a..].find("# Post-processing").unwrap();
    let text = format!("{}{}", &text[..a], &text[a + b..]);
    let p = dir.join("tiny.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_input_fails_before_any_work_naming_the_input() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let job = tiny_job(dp);
    let job = job.to_str().unwrap();
    // check and run agree: bounces = 0 is refused by both, naming the job's field.
    let bad = dp.join("bad.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(job)
            .unwrap()
            .replace("bounces = 2", "bounces = 0"),
    )
    .unwrap();
    let bad = bad.to_str().unwrap();
    assert_fails(
        &synosis(&["dataset", "check", bad], dp),
        &["render.bounces"],
    );
    assert_fails(
        &synosis(&["dataset", "run", bad, "--out", "o"], dp),
        &["render.bounces"],
    );
    assert!(!dp.join("o").exists(), "a refused job leaves no folder");
    // Images in flight: 1 to 64; renderers: 1 to 8 (usage errors: clap's exit code 2,
    // naming the option and its range, no folder), the same for `dataset run` and
    // `bench-gpu`, which share the options.
    for command in [
        &["dataset", "run", job, "--out", "o"][..],
        &["bench-gpu", "--job", job, "--out", "o"][..],
    ] {
        for (flag, value, range) in [
            ("--in-flight", "0", "1..=64"),
            ("--renderers", "9", "1..=8"),
        ] {
            let o = synosis(&[command, &[flag, value]].concat(), dp);
            assert_eq!(o.status.code(), Some(2), "{command:?} {flag} {value}");
            let err = text(&o.stderr);
            assert!(err.contains(flag) && err.contains(range), "{err}");
            assert!(!dp.join("o").exists());
        }
        // Several renderers with one image in flight: refused before any work.
        assert_fails(
            &synosis(
                &[command, &["--renderers", "2", "--in-flight", "1"]].concat(),
                dp,
            ),
            &["--renderers 2", "--in-flight 2 or more"],
        );
        assert!(!dp.join("o").exists(), "{command:?}");
    }
    // A missing job file: the OS error once.
    let e = assert_fails(
        &synosis(&["dataset", "run", "missing.toml", "--out", "o"], dp),
        &["missing.toml"],
    );
    assert_eq!(e.matches("No such file").count(), 1, "{e}");
    // --out under a file: refused before the renderer starts.
    std::fs::write(dp.join("afile"), "x").unwrap();
    assert_fails(
        &synosis(&["dataset", "run", job, "--out", "afile/sub"], dp),
        &["--out afile/sub", "afile"],
    );
    assert_fails(
        &synosis(
            &[
                "render",
                &format!("{ROOT}/scenes/demo.toml"),
                "--out",
                "afile/r",
            ],
            dp,
        ),
        &["--out afile/r"],
    );
    // Shard settings that would silently render the wrong part.
    let o = Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args(["dataset", "run", job, "--out", "o", "--shard-count", "4"])
        .current_dir(dp)
        .env_remove("JOB_COMPLETION_INDEX")
        .env_remove("SLURM_ARRAY_TASK_ID")
        .output()
        .unwrap();
    assert_fails(&o, &["without JOB_COMPLETION_INDEX"]);
    // A bad SYNOSIS_ACCEL is an error, not a silent default.
    let o = Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args(["dataset", "run", job, "--out", "o"])
        .current_dir(dp)
        .env("SYNOSIS_ACCEL", "sw")
        .output()
        .unwrap();
    assert_fails(&o, &["SYNOSIS_ACCEL=\"sw\""]);
    // render --width 1 names --width, not a field the user never set.
    let e = assert_fails(
        &synosis(
            &[
                "render",
                &format!("{ROOT}/scenes/demo.toml"),
                "--out",
                "r",
                "--width",
                "1",
                "--height",
                "1",
            ],
            dp,
        ),
        &["--width"],
    );
    assert!(!e.contains("pixel_um"), "{e}");
    assert!(!dp.join("o").exists() && !dp.join("r").exists());
}

#[test]
fn render_and_dataset_run_write_their_files_and_report_on_stdout() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let o = synosis(
        &[
            "render",
            &format!("{ROOT}/scenes/demo.toml"),
            "--out",
            "r",
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
        ],
        dp,
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    for f in [
        "radiance.exr",
        "image.png",
        "mask.png",
        "instances.png",
        "faces.png",
        "coverage.png",
    ] {
        assert!(dp.join("r").join(f).is_file(), "render wrote no {f}");
    }
    assert!(text(&o.stdout).contains("32x24"), "{}", text(&o.stdout));

    let job = tiny_job(dp);
    let job = job.to_str().unwrap();
    let o = synosis(
        &[
            "dataset",
            "run",
            job,
            "--out",
            "ds",
            "--quiet",
            "--profile",
            "run.json",
        ],
        dp,
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        text(&o.stdout).contains("1 images (0 already done, 1 rendered); dataset finished"),
        "{}",
        text(&o.stdout)
    );
    // The run's timeline: the image and its stages on the runner's thread, the GPU's
    // passes, and the busy share on stderr.
    let trace: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dp.join("run.json")).unwrap()).unwrap();
    let events = trace["traceEvents"].as_array().unwrap();
    let named = |n: &str| events.iter().any(|e| e["ph"] == "X" && e["name"] == n);
    for n in [
        "image 000000",
        "defects",
        "textures",
        "render",
        "write",
        "path trace",
        "annotate",
    ] {
        assert!(named(n), "no span {n} in the profile");
    }
    assert!(
        events.iter().any(|e| e["ph"] == "X" && e["cat"] == "gpu"),
        "no GPU pass in the profile"
    );
    assert!(text(&o.stderr).contains("GPU busy"), "{}", text(&o.stderr));
    for f in [
        "job.toml",
        "manifest.jsonl",
        "coco/train.json",
        "images/000000/image.png",
    ] {
        assert!(dp.join("ds").join(f).is_file(), "dataset run wrote no {f}");
    }
    // Again: nothing left to do, nothing rendered.
    let o = synosis(&["dataset", "run", job, "--out", "ds", "--quiet"], dp);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        text(&o.stdout).contains("(1 already done, 0 rendered)"),
        "{}",
        text(&o.stdout)
    );
}

/// `synosis render` with an OpenCV calibration, a thin lens and an EMVA 1288 sensor:
/// the calibration's size, a 16-bit PNG of 12-bit codes, the exposure on stderr; and
/// `--png16` next to `[sensor]` is refused naming it.
#[test]
fn render_with_calibration_lens_and_sensor() {
    let dir = tempfile::tempdir().unwrap();
    let dp = dir.path();
    std::fs::write(
        dp.join("cam.yaml"),
        "%YAML:1.0\n---\nimage_width: 40\nimage_height: 30\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 120., 0., 20.5, 0., 121., 14.2, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ -0.2, 0.05, 1.0e-3, 0., 0. ]\n",
    )
    .unwrap();
    let err = render_scene(
        dp,
        "s.toml",
        "[camera]\ncalibration = \"cam.yaml\"\nf_number = 4.0\n[light]\nradiance = 50.0\n[render]\nspp = 2\nbatch_spp = 2\n[sensor]\nbit_depth = 12\ngain_dn_per_electron = 0.4\nblooming = \"vertical\"\n",
        "out",
    );
    assert!(
        err.contains("sensor: exposure") && err.contains("12 bit"),
        "{err}"
    );
    let dec = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(dp.join("out/image.png")).unwrap(),
    ));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (40, 30));
    assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
    let codes: Vec<u16> = buf[..info.buffer_size()]
        .chunks(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect();
    let max = *codes.iter().max().unwrap();
    assert!(max <= 4095 && max > 0, "12-bit codes, max {max}");
    assert!(dp.join("out/mask.png").exists());
    assert_fails(
        &synosis(&["render", "s.toml", "--out", "out2", "--png16"], dp),
        &["--png16", "bit_depth"],
    );
    // A scene file's noise target with `analytic_rays_max`: the render chooses its rays at
    // the first check (a target it cannot meet, so that it samples on to `spp`).
    let err = render_scene(
        dp,
        "t.toml",
        "[camera]\ncalibration = \"cam.yaml\"\nf_number = 4.0\n[light]\nradiance = 50.0\n[render]\nspp = 6\nbatch_spp = 2\nnoise_target = 0.01\nmin_spp = 2\nanalytic_rays = 2\nanalytic_rays_max = 8\n[sensor]\n",
        "out3",
    );
    assert!(
        err.contains("noise check: 2 spp")
            && err.contains("analytic rays: ")
            && err.contains("chosen in [1, 8]")
            && err.contains("stopped at 6 spp"),
        "{err}"
    );
    assert!(
        !dp.join("out3/spp.png").exists(),
        "without adaptive_radius every pixel takes the image's spp: no spp.png"
    );
    // With `adaptive_radius` each pixel stops at its own samples: spp.png (16-bit) holds
    // them, its most the image's spp, its mean the last check's.
    let err = render_scene(
        dp,
        "a.toml",
        "[camera]\ncalibration = \"cam.yaml\"\nf_number = 4.0\n[light]\nradiance = 50.0\n[render]\nspp = 64\nbatch_spp = 4\nnoise_target = 1.0\nmin_spp = 4\nadaptive_radius = 1\n[sensor]\n",
        "out4",
    );
    let last = err
        .lines()
        .filter_map(|l| l.strip_prefix("noise check: "))
        .next_back()
        .unwrap_or_else(|| panic!("no noise check: {err}"));
    // "N spp (mean M), ..."
    let (spp, mean) = last.split_once(" spp (mean ").unwrap();
    let spp: u32 = spp.parse().unwrap();
    let mean: f64 = mean.split_once(')').unwrap().0.parse().unwrap();
    let img = image::open(dp.join("out4/spp.png")).unwrap();
    assert_eq!(img.color(), image::ColorType::L16);
    let img = img.into_luma16();
    assert_eq!(img.dimensions(), (40, 30));
    let counts: Vec<u32> = img.pixels().map(|p| p.0[0] as u32).collect();
    let png_mean = counts.iter().sum::<u32>() as f64 / counts.len() as f64;
    assert_eq!(counts.iter().max(), Some(&spp), "{err}");
    assert!(
        counts.iter().any(|&c| c < spp),
        "no pixel stopped early: {err}"
    );
    assert!(
        (png_mean - mean).abs() <= 0.05,
        "{png_mean} against {mean}: {err}"
    );
}

#[test]
fn compile_runs_each_backends_pipelines_and_names_them() {
    // tools/test runs `synosis compile` before the tests, so here the cache is warm and
    // this is quick; what it shows is that every pass runs on its tiny scene without a
    // validation message and that every shader variant of the backend was dispatched (the
    // command fails on either), and that each backend is reported.
    let dir = tempfile::tempdir().unwrap();
    let o = synosis(&["compile", "--accel", "software-wide"], dir.path());
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    assert!(o.status.success(), "stdout {out}\nstderr {err}");
    assert!(
        err.contains("compiling the pipelines of software-wide on "),
        "{err}"
    );
    assert!(
        err.lines()
            .any(|l| l.trim_start().starts_with("software-wide ")),
        "{err}"
    );
    assert!(err.contains("done in "), "{err}");
    assert!(
        !err.contains("ray-query"),
        "only the backend asked for: {err}"
    );
    let o = synosis(&["compile", "--accel", "wide"], dir.path());
    assert_eq!(o.status.code(), Some(2), "clap refuses an unknown backend");
    assert!(
        text(&o.stderr).contains("software-wide"),
        "and names the allowed ones"
    );
}

/// `synosis bench-gpu` (what `tools/bench-gpu` runs) on lavapipe at a tiny size: the table
/// with each stage and the GPU busy share, the JSON beside it, and the Chrome trace.
#[test]
fn bench_gpu_writes_its_table() {
    let dir = tempfile::tempdir().unwrap();
    let dp = dir.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let job = root.join("scenes/smoke-dataset.toml");
    let o = synosis(
        &[
            "bench-gpu",
            "--job",
            job.to_str().unwrap(),
            "--out",
            "data",
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--rays-side",
            "32",
            "--json",
            "b.json",
            "--profile",
            "run.json",
        ],
        dp,
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = text(&o.stdout);
    for row in [
        "| per image |",
        "| per image from the first render on (a long run) |",
        "| stage textures |",
        "| stage render.path_trace_gpu |",
        "| stage write |",
        "| GPU busy |",
        "| CPU busy |",
        "| device memory in live buffers and images",
        "| rays (",
    ] {
        assert!(table.contains(row), "no row {row} in\n{table}");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dp.join("b.json")).unwrap()).unwrap();
    let busy = v["gpu_busy_fraction"].as_f64().unwrap();
    assert!(busy > 0.0 && busy <= 1.0, "{busy}");
    // The process's CPU time over the loop on all cores (the ticks are 10 ms, the loop
    // several seconds).
    let cpu = v["cpu_busy_fraction"].as_f64().unwrap();
    assert!(cpu > 0.0 && cpu <= 1.05, "{cpu}");
    // From the first render on: no longer than the whole loop's time per image.
    let (steady, per) = (
        v["steady_per_image_s"].as_f64().unwrap(),
        v["per_image_s"].as_f64().unwrap(),
    );
    assert!(steady > 0.0 && steady <= per, "{steady} {per}");
    assert!(v["images"].as_u64().unwrap() > 0);
    assert!(v["rays"]["primary_mrays_s"].as_f64().unwrap() > 0.0);
    // The device memory after each image (the run's profile counters): some held.
    let m = &v["device_memory"];
    assert!(m["first_mib"].as_f64().unwrap() > 0.0, "{m}");
    assert!(
        m["most_mib"].as_f64().unwrap() >= m["last_mib"].as_f64().unwrap(),
        "{m}"
    );
    assert!(m["last_allocations"].as_f64().unwrap() >= 1.0, "{m}");
    let trace: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dp.join("run.json")).unwrap()).unwrap();
    let counted = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["ph"] == "C" && e["name"] == "device memory (MiB)")
        .count();
    assert_eq!(counted as u64, v["images"].as_u64().unwrap(), "{trace}");
    // The default images in flight: 1 on a CPU Vulkan device (lavapipe), 3 on a GPU.
    let cpu = v["device"].as_str().unwrap().contains("llvmpipe");
    let want = if cpu { 1 } else { 3 };
    assert_eq!(v["in_flight"].as_u64(), Some(want));
    assert!(
        table.contains(&format!("| images in flight | {want} |")),
        "{table}"
    );
    // One renderer (device context) on a CPU Vulkan device.
    if cpu {
        assert_eq!(v["renderers"].as_u64(), Some(1));
        assert!(
            table.contains("| renderers (device contexts) | 1 |"),
            "{table}"
        );
    }
    // `--consecutive`: the job's first instance with all its views (images 0.. in the
    // job's order), not a shard spread over the job; the run is left unfinished.
    let o = synosis(
        &[
            "bench-gpu",
            "--job",
            job.to_str().unwrap(),
            "--out",
            "first",
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--rays-side",
            "0",
            "--consecutive",
            "--json",
            "c.json",
        ],
        dp,
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = text(&o.stdout);
    assert!(table.contains("1 instance(s) of"), "{table}");
    assert!(table.contains("the first, consecutive"), "{table}");
    let c: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dp.join("c.json")).unwrap()).unwrap();
    assert_eq!(c["consecutive"].as_bool(), Some(true));
    let indices: Vec<usize> =
        synosis::dataset::read_manifest(&dp.join("first/manifests/shard-0-of-1.jsonl"), false)
            .unwrap()
            .iter()
            .map(|e| e.index)
            .collect();
    assert!(!indices.is_empty());
    assert_eq!(indices, (0..indices.len()).collect::<Vec<usize>>());
    assert_eq!(c["images"].as_u64(), Some(indices.len() as u64));
    assert!(!dp.join("first/manifest.jsonl").exists());
    // A non-empty work folder is refused before any work.
    let o = synosis(
        &["bench-gpu", "--job", job.to_str().unwrap(), "--out", "data"],
        dp,
    );
    assert!(!o.status.success());
    assert!(
        text(&o.stderr).contains("must be empty"),
        "{}",
        text(&o.stderr)
    );
}
