//! Reliability of the file readers and writers (docs/reliability.md): reproducible EXR
//! bytes, floats that read back identical, size limits checked before allocating, and a
//! bounded fuzz loop per reader (truncated, flipped, oversized, random bytes: an error,
//! never a panic or an abort).

use std::path::{Path, PathBuf};

use synosis::dataset::seed::splitmix64;

/// Deterministic pseudo-random bytes and numbers for the fuzz loops.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = splitmix64(self.0);
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Cases per reader: enough to hit truncations and flips at many places, fast in CI.
const CASES: usize = 150;

/// Runs `read` on mutations of `seed` (truncations, byte flips, byte runs, random
/// files); every case must return (Ok or Err) without panicking.
fn fuzz(name: &str, seed: &[u8], dir: &Path, ext: &str, read: &dyn Fn(&Path) -> bool) {
    let mut rng = Rng(0x5EED ^ seed.len() as u64);
    let path = dir.join(format!("fuzz-{name}.{ext}"));
    let mut errors = 0;
    for case in 0..CASES {
        let mut b = seed.to_vec();
        match case % 4 {
            0 => b.truncate(rng.below(seed.len())),
            1 => {
                for _ in 0..1 + rng.below(8) {
                    let i = rng.below(b.len());
                    b[i] ^= 1 << rng.below(8);
                }
            }
            2 => {
                // A run of 0xff or 0x00 (oversized or zero counts in headers).
                let i = rng.below(b.len());
                let v = if rng.next() & 1 == 0 { 0xff } else { 0x00 };
                for x in b.iter_mut().skip(i).take(1 + rng.below(8)) {
                    *x = v;
                }
            }
            _ => b = (0..rng.below(512)).map(|_| rng.next() as u8).collect(),
        }
        std::fs::write(&path, &b).unwrap();
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| read(&path)));
        match r {
            Ok(ok) => errors += (!ok) as usize,
            Err(_) => panic!(
                "{name}: the reader panicked on case {case} (bytes kept in {})",
                path.display()
            ),
        }
    }
    // Most mutations must be refused (a reader that accepts anything proves nothing).
    assert!(
        errors > CASES / 4,
        "{name}: only {errors} of {CASES} refused"
    );
}

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn exr_bytes_are_reproducible() {
    // 300 x 200 at 64 x 64 tiles: 20 chunks, compressed in parallel.
    let (w, h) = (300, 200);
    let mut rng = Rng(3);
    let data: Vec<f32> = (0..w * h)
        .map(|_| (rng.next() >> 40) as f32 * 1e-6)
        .collect();
    let d = tmp();
    let mut first: Option<Vec<u8>> = None;
    for k in 0..6 {
        let p = d.path().join(format!("r{k}.exr"));
        synosis::image_io::write_exr_f32(&p, w, h, "Y", &data).unwrap();
        let b = std::fs::read(&p).unwrap();
        match &first {
            None => first = Some(b),
            Some(f) => assert!(f == &b, "write {k} gave other bytes"),
        }
    }
    let (rw, rh, back) = synosis::image_io::read_exr_f32(&d.path().join("r0.exr")).unwrap();
    assert_eq!((rw, rh), (w, h));
    assert!(back == data);
}

#[test]
fn floats_written_to_json_read_back_identical() {
    let mut rng = Rng(9);
    for i in 0..20_000 {
        let x = match i % 3 {
            0 => f64::from_bits(rng.next() >> 2), // positive, every exponent
            1 => (rng.next() >> 11) as f64 / (1u64 << 53) as f64, // [0, 1)
            _ => (rng.next() >> 11) as f64 * 1e-9,
        };
        if !x.is_finite() {
            continue;
        }
        let s = serde_json::to_string(&x).unwrap();
        let y: f64 = serde_json::from_str(&s).unwrap();
        assert_eq!(x.to_bits(), y.to_bits(), "{x:e} -> {s} -> {y:e}");
    }
}

/// A valid EXR with its data window patched to `w` x `h` (nothing else changed).
fn exr_claiming(dir: &Path, w: i32, h: i32) -> PathBuf {
    let p = dir.join("claims.exr");
    synosis::image_io::write_exr_f32(&p, 8, 8, "Y", &[0.5; 64]).unwrap();
    let mut b = std::fs::read(&p).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = b
        .windows(key.len())
        .position(|x| x == key)
        .expect("dataWindow attribute")
        + key.len()
        + 4;
    b[at + 8..at + 12].copy_from_slice(&(w - 1).to_le_bytes());
    b[at + 12..at + 16].copy_from_slice(&(h - 1).to_le_bytes());
    std::fs::write(&p, &b).unwrap();
    p
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG whose header (with a valid checksum) claims `w` x `h` 8-bit gray pixels.
fn png_claiming(dir: &Path, w: u32, h: u32) -> PathBuf {
    let p = dir.join("claims.png");
    synosis::image_io::write_png_gray8(&p, 1, 1, &[7]).unwrap();
    let mut b = std::fs::read(&p).unwrap();
    // IHDR data starts at 16 (8 signature + 4 length + 4 type); its CRC covers type + data.
    b[16..20].copy_from_slice(&w.to_be_bytes());
    b[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = crc32(&b[12..29]);
    b[29..33].copy_from_slice(&crc.to_be_bytes());
    std::fs::write(&p, &b).unwrap();
    p
}

#[test]
fn oversized_headers_are_refused_before_allocating() {
    let d = tmp();
    let p = exr_claiming(d.path(), 99_999, 99_999);
    let e = synosis::image_io::read_exr_f32(&p).unwrap_err().to_string();
    assert!(e.contains("99999 x 99999") && e.contains("16384"), "{e}");
    let e = synosis::texture::read_exr(&p, 1.0).unwrap_err().to_string();
    assert!(e.contains("claims.exr") && e.contains("16384"), "{e}");

    // metrics: 20000 x 20000 would take about 12 GB; refused with the limit named.
    let p = png_claiming(d.path(), 20_000, 20_000);
    let e = synosis::metrics::GrayImage::load(&p)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("claims.png") && e.contains("20000 x 20000") && e.contains("Mpixel"),
        "{e}"
    );
    // The dataset's PNG reader: limit of the image decoder.
    let e = synosis::dataset::files::read_gray8(&p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("claims.png"), "{e}");

    // Text files: a 17 MiB job file.
    let big = d.path().join("big.toml");
    let f = std::fs::File::create(&big).unwrap();
    f.set_len(17 << 20).unwrap();
    let e = synosis::dataset::Job::load(&big).unwrap_err().to_string();
    assert!(
        e.contains("big.toml") && e.contains("16777216 bytes"),
        "{e}"
    );
    let e = synosis::scene::config::SceneConfig::load(&big)
        .unwrap_err()
        .to_string();
    assert!(e.contains("big.toml") && e.contains("limit"), "{e}");
}

#[test]
fn texture_maps_need_a_y_channel_and_a_finite_sample() {
    let d = tmp();
    let p = d.path().join("z.exr");
    synosis::image_io::write_exr_f32(&p, 4, 4, "Z", &[1.0; 16]).unwrap();
    let e = synosis::texture::read_exr(&p, 1.0).unwrap_err().to_string();
    assert!(e.contains("no channel named Y") && e.contains("Z"), "{e}");
    let p = d.path().join("nan.exr");
    let mut v = vec![f32::NAN; 16];
    v[3] = f32::INFINITY;
    synosis::image_io::write_exr_f32(&p, 4, 4, "Y", &v).unwrap();
    let e = synosis::texture::read_exr(&p, 1.0).unwrap_err().to_string();
    assert!(e.contains("no finite sample"), "{e}");
    // One finite sample is enough: the others get the mean (documented).
    v[5] = 2.0;
    synosis::image_io::write_exr_f32(&p, 4, 4, "Y", &v).unwrap();
    let m = synosis::texture::read_exr(&p, 1.0).unwrap();
    assert!(m.data.iter().all(|&x| x == 2.0));
}

#[test]
fn every_reader_survives_fuzzed_input() {
    let d = tmp();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // EXR: the dataset's radiance reader and the texture height reader.
    let exr = d.path().join("seed.exr");
    synosis::image_io::write_exr_f32(&exr, 16, 8, "Y", &[0.25; 128]).unwrap();
    let exr = std::fs::read(&exr).unwrap();
    fuzz("exr-radiance", &exr, d.path(), "exr", &|p| {
        synosis::image_io::read_exr_f32(p).is_ok()
    });
    fuzz("exr-height", &exr, d.path(), "exr", &|p| {
        synosis::texture::read_exr(p, 1.0).is_ok()
    });
    // PNG: dataset labels and metrics images.
    let png = d.path().join("seed.png");
    synosis::image_io::write_png_gray16(&png, 9, 7, &[300; 63]).unwrap();
    let png = std::fs::read(&png).unwrap();
    fuzz("png-dataset", &png, d.path(), "png", &|p| {
        synosis::dataset::files::read_gray16(p).is_ok()
    });
    fuzz("png-metrics", &png, d.path(), "png", &|p| {
        synosis::metrics::GrayImage::load(p).is_ok()
    });
    // GLB meshes.
    let glb = std::fs::read(root.join("scenes/testbody-b.glb")).unwrap();
    fuzz("glb", &glb, d.path(), "glb", &|p| {
        synosis::scene::import_mesh(p, synosis::scene::Degenerates::Drop).is_ok()
    });
    // Measurement files (Alicona ASCII).
    let mut xyz = String::from("# x y z\n");
    for j in 0..6 {
        for i in 0..6 {
            xyz.push_str(&format!(
                "{} {} {}\n",
                i as f64 * 1e-6,
                j as f64 * 1e-6,
                (i * j) as f64 * 1e-7
            ));
        }
    }
    fuzz("xyz", xyz.as_bytes(), d.path(), "xyz", &|p| {
        synosis::texture::read_xyz(p, synosis::texture::XyzUnit::M).is_ok()
    });
    // Job, scene and defect-spec TOML.
    let job = std::fs::read(root.join("scenes/smoke-dataset.toml")).unwrap();
    std::fs::copy(
        root.join("scenes/defects-smoke.toml"),
        d.path().join("defects-smoke.toml"),
    )
    .unwrap();
    assert!(synosis::dataset::Job::load(&root.join("scenes/smoke-dataset.toml")).is_ok());
    fuzz("job", &job, d.path(), "toml", &|p| {
        synosis::dataset::Job::load(p).is_ok()
    });
    let scene = std::fs::read(root.join("scenes/demo.toml")).unwrap();
    fuzz("scene", &scene, d.path(), "toml", &|p| {
        synosis::scene::config::SceneConfig::load(p).is_ok()
    });
    let spec = std::fs::read(root.join("scenes/defects-paper.toml")).unwrap();
    fuzz("defect-spec", &spec, d.path(), "toml", &|p| {
        synosis::defect::DefectSpec::load(p).is_ok()
    });
    // LabelMe JSON.
    let lm = br#"{"version": "5.0.1", "flags": {}, "shapes": [{"label": "dent", "points": [[1.5, 1.5], [4.5, 1.5], [4.5, 3.5]], "group_id": 1, "shape_type": "polygon", "flags": {}}], "imagePath": "image.png", "imageData": null, "imageHeight": 8, "imageWidth": 8}"#;
    fuzz("labelme", lm, d.path(), "json", &|p| {
        synosis::metrics::labelme::LabelMe::load(p).is_ok()
    });
}
