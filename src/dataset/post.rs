//! Post-processing (paper, "Pipeline Evaluation"): named, optional steps applied in the
//! job's order, each a small pure function on f32 images.
//!
//! Intensity scale: every step works on **8-bit units, 0..=255, as f32** (the scale
//! `synosis compare` reads, and the one the paper's biases 34 / 39 / 33 are given in).
//! The renderer's linear radiance L enters as `255 * exposure * L` (`[sensor]`, through
//! `render::pixels::Exposure::units8`, the pixel pipeline `synosis render` uses too); the
//! thresholds the paper gives as fractions (blooming 0.95, visibility 0.05) are
//! fractions of 255. Values are clamped to [0, 255] and rounded only when `image.png`
//! is written, except blooming, which clips as the paper says.

use std::collections::{BTreeMap, BTreeSet};

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::render::optics::Border;
pub use crate::render::optics::Kernel;
/// Full scale of the image values (the pixel pipeline's 8-bit units).
pub use crate::render::pixels::FULL_SCALE;
/// Rounds to 8 bit with clamping (NaN gives 0): the pixel pipeline's last step.
pub use crate::render::pixels::quantise_units8 as quantize;

/// The paper's linear factor and bias per texture type.
pub fn paper_linear() -> BTreeMap<String, [f64; 2]> {
    BTreeMap::from([
        ("sandblasted".to_string(), [0.632, 34.0]),
        ("parallel".to_string(), [1.481, 39.0]),
        ("spiral".to_string(), [1.526, 33.0]),
    ])
}

fn one() -> f64 {
    1.0
}
fn half() -> f64 {
    0.5
}
fn five() -> f64 {
    5.0
}
fn bloom_threshold() -> f64 {
    0.95
}
fn bloom_width() -> u32 {
    64
}
fn bloom_factor() -> f64 {
    0.02
}
fn one_px() -> u32 {
    1
}
fn vis_threshold() -> f64 {
    0.05
}

/// One post-processing step, as written in the job (`[[postprocess]] step = "..."`).
/// Defaults are the paper's values.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(tag = "step", rename_all = "snake_case", deny_unknown_fields)]
pub enum PostStep {
    /// v' = factor * v + bias, per texture type (finish name up to its first '-').
    Linear {
        #[serde(default = "paper_linear")]
        by_type: BTreeMap<String, [f64; 2]>,
    },
    /// Hendrycks et al. 2019 defocus blur: a disk of `radius` px smoothed by a 3x3
    /// Gaussian of sigma `alias_sigma` (0 = none).
    Defocus {
        #[serde(default = "one")]
        radius: f64,
        #[serde(default = "half")]
        alias_sigma: f64,
    },
    /// Gaussian noise on the background (pixels not on the object): per image the
    /// standard deviation is drawn from U(0, amplitude).
    BackgroundNoise {
        #[serde(default = "five")]
        amplitude: f64,
    },
    /// Vertical blooming: column maxima at or above `threshold` (fraction of full
    /// scale) are box-filtered across columns (`width` px), scaled by `factor` and
    /// added to the whole column, clipped to full scale.
    Blooming {
        #[serde(default = "bloom_threshold")]
        threshold: f64,
        #[serde(default = "bloom_width")]
        width: u32,
        #[serde(default = "bloom_factor")]
        factor: f64,
    },
    /// Grows every defect mask by `pixels` (3x3 square element per pixel) into
    /// background, as manual annotations cover the rim.
    DilateMasks {
        #[serde(default = "one_px")]
        pixels: u32,
    },
    /// Drops defects whose visibility (|mean inside - mean of the ring|, fraction of
    /// full scale; ring = mask dilated twice minus mask) is under `threshold`.
    VisibilityFilter {
        #[serde(default = "vis_threshold")]
        threshold: f64,
    },
}

impl PostStep {
    pub fn name(&self) -> &'static str {
        match self {
            PostStep::Linear { .. } => "linear",
            PostStep::Defocus { .. } => "defocus",
            PostStep::BackgroundNoise { .. } => "background_noise",
            PostStep::Blooming { .. } => "blooming",
            PostStep::DilateMasks { .. } => "dilate_masks",
            PostStep::VisibilityFilter { .. } => "visibility_filter",
        }
    }

    /// Checks ranges; `types` are the job's texture types. Err: (field, value, allowed).
    pub fn validate(&self, types: &BTreeSet<String>) -> Result<(), (String, String, String)> {
        let range = |f: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err((
                    f.to_string(),
                    v.to_string(),
                    format!("must be in [{lo}, {hi}]"),
                ))
            }
        };
        match self {
            PostStep::Linear { by_type } => {
                for t in types {
                    let Some(&[f, b]) = by_type.get(t) else {
                        let have: Vec<&str> = by_type.keys().map(String::as_str).collect();
                        return Err((
                            "by_type".into(),
                            format!("{{{}}}", have.join(", ")),
                            format!("needs a [factor, bias] for texture type {t:?}"),
                        ));
                    };
                    range(&format!("by_type.{t}[0]"), f, 0.0, 1.0e3)?;
                    range(&format!("by_type.{t}[1]"), b, -255.0, 255.0)?;
                }
                Ok(())
            }
            PostStep::Defocus {
                radius,
                alias_sigma,
            } => {
                range("radius", *radius, 0.0, 8.0)?;
                range("alias_sigma", *alias_sigma, 0.0, 3.0)
            }
            PostStep::BackgroundNoise { amplitude } => range("amplitude", *amplitude, 0.0, 255.0),
            PostStep::Blooming {
                threshold,
                width,
                factor,
            } => {
                range("threshold", *threshold, 0.0, 1.0)?;
                range("width", *width as f64, 1.0, 4096.0)?;
                range("factor", *factor, 0.0, 10.0)
            }
            PostStep::DilateMasks { pixels } => range("pixels", *pixels as f64, 0.0, 64.0),
            PostStep::VisibilityFilter { threshold } => range("threshold", *threshold, 0.0, 1.0),
        }
    }
}

/// An image with its labels, as post-processing sees it. `image` in 8-bit units.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub image: Vec<f32>,
    pub class: Vec<u8>,
    pub instance: Vec<u16>,
    /// 1 where the object is seen, 0 on the background (table, nothing).
    pub object: Vec<u8>,
}

/// What became of one defect.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DefectVisibility {
    pub instance: u16,
    pub class: u8,
    /// Visible pixels in the raw annotation.
    pub pixels: usize,
    /// |mean inside - mean of the ring| / 255 on the image the filter saw (or the final
    /// image if there is no filter step).
    pub visibility: f64,
    pub kept: bool,
    /// The defect spec entry it was drawn from ("big dent", ...; docs/defects.md), filled
    /// in by the dataset runner from the instance's defect set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
}

/// The result of the post-processing of one image.
#[derive(Clone, Debug)]
pub struct PostResult {
    pub frame: Frame,
    pub defects: Vec<DefectVisibility>,
    /// The background noise sigma drawn for this image, if that step ran.
    pub noise_sigma: Option<f64>,
}

/// Runs `steps` in order. `texture_type` picks the linear row; `seed` drives the noise
/// (derived from the image seed, so re-running post-processing gives the same image).
pub fn apply(steps: &[PostStep], texture_type: &str, seed: u64, mut f: Frame) -> PostResult {
    let raw: Vec<(u16, u8, usize)> = defect_pixels(&f.class, &f.instance);
    let mut vis: BTreeMap<u16, f64> = BTreeMap::new();
    let mut noise_sigma = None;
    let mut filtered = false;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    for step in steps {
        match step {
            PostStep::Linear { by_type } => {
                // Validation guarantees a row for every finish's type.
                let [a, b] = by_type.get(texture_type).copied().unwrap_or([1.0, 0.0]);
                f.image = linear(&f.image, a as f32, b as f32);
            }
            PostStep::Defocus {
                radius,
                alias_sigma,
            } => {
                let k = defocus_kernel(*radius, *alias_sigma);
                f.image = convolve(&f.image, f.width, f.height, &k);
            }
            PostStep::BackgroundNoise { amplitude } => {
                let sigma = if *amplitude > 0.0 {
                    rng.random_range(0.0..=*amplitude)
                } else {
                    0.0
                };
                noise_sigma = Some(sigma);
                f.image = background_noise(&f.image, &f.object, sigma as f32, rng.random());
            }
            PostStep::Blooming {
                threshold,
                width,
                factor,
            } => {
                f.image = blooming(
                    &f.image,
                    f.width,
                    f.height,
                    *threshold as f32 * FULL_SCALE,
                    *width as usize,
                    *factor as f32,
                );
            }
            PostStep::DilateMasks { pixels } => {
                for _ in 0..*pixels {
                    (f.class, f.instance) = dilate_labels(&f.class, &f.instance, f.width, f.height);
                }
            }
            PostStep::VisibilityFilter { threshold } => {
                filtered = true;
                let v = visibilities(&f.image, &f.instance, f.width, f.height);
                for (&id, &value) in &v {
                    vis.insert(id, value);
                    if value < *threshold {
                        for (c, i) in f.class.iter_mut().zip(f.instance.iter_mut()) {
                            if *i == id {
                                *c = 0;
                                *i = 0;
                            }
                        }
                    }
                }
            }
        }
    }
    if !filtered {
        vis = visibilities(&f.image, &f.instance, f.width, f.height);
    }
    let kept: BTreeSet<u16> = f.instance.iter().copied().filter(|&i| i != 0).collect();
    let defects = raw
        .into_iter()
        .map(|(instance, class, pixels)| DefectVisibility {
            instance,
            class,
            pixels,
            visibility: vis.get(&instance).copied().unwrap_or(0.0),
            kept: kept.contains(&instance),
            kind: None,
        })
        .collect();
    PostResult {
        frame: f,
        defects,
        noise_sigma,
    }
}

/// (instance, class, pixel count) of every defect present, by instance id.
pub fn defect_pixels(class: &[u8], instance: &[u16]) -> Vec<(u16, u8, usize)> {
    let mut m: BTreeMap<u16, (u8, usize)> = BTreeMap::new();
    for (&c, &i) in class.iter().zip(instance) {
        if i != 0 {
            let e = m.entry(i).or_insert((c, 0));
            e.1 += 1;
        }
    }
    m.into_iter().map(|(i, (c, n))| (i, c, n)).collect()
}

/// v' = factor * v + bias.
pub fn linear(image: &[f32], factor: f32, bias: f32) -> Vec<f32> {
    image.iter().map(|&v| factor * v + bias).collect()
}

/// Hendrycks' defocus kernel: the pixels with x^2 + y^2 <= r^2 (normalised), smoothed
/// by a 3x3 Gaussian of sigma `alias_sigma` (OpenCV's 3x3 `GaussianBlur`).
pub fn defocus_kernel(radius: f64, alias_sigma: f64) -> Kernel {
    let r = radius.ceil().max(0.0) as i64;
    let pad = if alias_sigma > 0.0 { 1 } else { 0 };
    let half = r + pad;
    let size = (2 * half + 1) as usize;
    let mut disk = vec![0.0f64; size * size];
    for y in -r..=r {
        for x in -r..=r {
            if ((x * x + y * y) as f64) <= radius * radius {
                disk[((y + half) as usize) * size + (x + half) as usize] = 1.0;
            }
        }
    }
    let sum: f64 = disk.iter().sum();
    disk.iter_mut().for_each(|v| *v /= sum);
    if alias_sigma > 0.0 {
        let g1 = (-1.0 / (2.0 * alias_sigma * alias_sigma)).exp();
        let g = [
            g1 / (1.0 + 2.0 * g1),
            1.0 / (1.0 + 2.0 * g1),
            g1 / (1.0 + 2.0 * g1),
        ];
        let mut out = vec![0.0f64; size * size];
        // The disk sits `pad` = 1 px inside the grid, so nothing leaves it.
        for y in 0..size {
            for x in 0..size {
                let mut acc = 0.0;
                for (dy, gy) in g.iter().enumerate() {
                    for (dx, gx) in g.iter().enumerate() {
                        let (sx, sy) = (x as i64 + dx as i64 - 1, y as i64 + dy as i64 - 1);
                        if (0..size as i64).contains(&sx) && (0..size as i64).contains(&sy) {
                            acc += gy * gx * disk[sy as usize * size + sx as usize];
                        }
                    }
                }
                out[y * size + x] = acc;
            }
        }
        disk = out;
    }
    Kernel {
        radius: half as usize,
        weights: disk.into_iter().map(|v| v as f32).collect(),
    }
}

/// 2-D correlation with `k` (centred), reflect-101 borders (OpenCV's default), as
/// [`render::optics::convolve`](crate::render::optics::convolve) computes it.
pub fn convolve(image: &[f32], width: usize, height: usize, k: &Kernel) -> Vec<f32> {
    crate::render::optics::convolve(image, width, height, k, Border::Reflect101)
}

/// Adds N(0, sigma^2) noise where `object` is 0; the object is left alone.
pub fn background_noise(image: &[f32], object: &[u8], sigma: f32, seed: u64) -> Vec<f32> {
    if sigma <= 0.0 {
        return image.to_vec();
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    // sigma > 0 and finite (validated), so Normal::new cannot fail.
    let normal = Normal::new(0.0f32, sigma).unwrap_or_else(|_| unreachable!("sigma > 0"));
    image
        .iter()
        .zip(object)
        .map(|(&v, &o)| {
            if o == 0 {
                v + normal.sample(&mut rng)
            } else {
                v
            }
        })
        .collect()
}

/// Vertical blooming. `threshold` in image units; the box covers columns
/// [x - width/2, x - width/2 + width - 1] (OpenCV's anchor), reflect-101 at the edges.
pub fn blooming(
    image: &[f32],
    width: usize,
    height: usize,
    threshold: f32,
    box_width: usize,
    factor: f32,
) -> Vec<f32> {
    let mut colmax = vec![f32::NEG_INFINITY; width];
    for y in 0..height {
        for x in 0..width {
            colmax[x] = colmax[x].max(image[y * width + x]);
        }
    }
    let masked: Vec<f32> = colmax
        .iter()
        .map(|&m| if m >= threshold { m } else { 0.0 })
        .collect();
    let half = (box_width / 2) as i64;
    let add: Vec<f32> = (0..width as i64)
        .map(|x| {
            let s: f32 = (0..box_width as i64)
                .map(|k| masked[Border::Reflect101.source(x - half + k, width)])
                .sum();
            factor * s / box_width as f32
        })
        .collect();
    image
        .iter()
        .enumerate()
        .map(|(i, &v)| (v + add[i % width]).clamp(0.0, FULL_SCALE))
        .collect()
}

/// One step of label dilation with a 3x3 square: a background pixel takes the smallest
/// instance id among its 8 neighbours (and its class); defects never overwrite each other.
pub fn dilate_labels(
    class: &[u8],
    instance: &[u16],
    width: usize,
    height: usize,
) -> (Vec<u8>, Vec<u16>) {
    let mut c2 = class.to_vec();
    let mut i2 = instance.to_vec();
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            if instance[p] != 0 {
                continue;
            }
            let mut best: Option<usize> = None;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (sx, sy) = (x as i64 + dx, y as i64 + dy);
                    if sx < 0 || sy < 0 || sx >= width as i64 || sy >= height as i64 {
                        continue;
                    }
                    let q = sy as usize * width + sx as usize;
                    if instance[q] != 0 && best.is_none_or(|b| instance[q] < instance[b]) {
                        best = Some(q);
                    }
                }
            }
            if let Some(q) = best {
                c2[p] = class[q];
                i2[p] = instance[q];
            }
        }
    }
    (c2, i2)
}

/// Visibility of every defect: |mean(image inside) - mean(image on the ring)| / 255,
/// ring = the defect's mask dilated twice (3x3 square, i.e. within 2 px in x and y)
/// minus the mask. A defect with an empty ring has visibility 0.
pub fn visibilities(
    image: &[f32],
    instance: &[u16],
    width: usize,
    height: usize,
) -> BTreeMap<u16, f64> {
    // Bounding boxes first, so each defect costs only its neighbourhood.
    let mut boxes: BTreeMap<u16, [usize; 4]> = BTreeMap::new();
    for y in 0..height {
        for x in 0..width {
            let id = instance[y * width + x];
            if id != 0 {
                let b = boxes.entry(id).or_insert([x, y, x, y]);
                b[0] = b[0].min(x);
                b[1] = b[1].min(y);
                b[2] = b[2].max(x);
                b[3] = b[3].max(y);
            }
        }
    }
    let mut out = BTreeMap::new();
    for (id, [x0, y0, x1, y1]) in boxes {
        let (x0, y0) = (x0.saturating_sub(2), y0.saturating_sub(2));
        let (x1, y1) = ((x1 + 2).min(width - 1), (y1 + 2).min(height - 1));
        let (mut si, mut ni, mut sr, mut nr) = (0.0f64, 0usize, 0.0f64, 0usize);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let p = y * width + x;
                if instance[p] == id {
                    si += image[p] as f64;
                    ni += 1;
                    continue;
                }
                let near = (y.saturating_sub(2)..=(y + 2).min(height - 1)).any(|sy| {
                    (x.saturating_sub(2)..=(x + 2).min(width - 1))
                        .any(|sx| instance[sy * width + sx] == id)
                });
                if near {
                    sr += image[p] as f64;
                    nr += 1;
                }
            }
        }
        let v = if ni == 0 || nr == 0 {
            0.0
        } else {
            (si / ni as f64 - sr / nr as f64).abs() / FULL_SCALE as f64
        };
        out.insert(id, v);
    }
    out
}
