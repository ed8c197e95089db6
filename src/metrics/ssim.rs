//! SSIM (Wang et al. 2004) with a Gaussian window, matching scikit-image's
//! `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`:
//! scipy's `gaussian_filter` (truncate 3.5, so 11 taps; mode "reflect") on the images,
//! their squares and their product, then the SSIM map.
//!
//! Everything is f32 for speed. Second moments are taken of the image minus a constant
//! offset: variance and covariance do not change, but E[x^2] - E[x]^2 stops cancelling
//! catastrophically (f32 has 24 bits; 255^2 already uses 16 of them).

use rayon::prelude::*;

use super::MetricsError;
use super::gray::{DATA_RANGE, GrayImage, check_same_size};
use super::masks::{Mask, Rect};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimParams {
    pub sigma: f64,
    pub k1: f64,
    pub k2: f64,
    pub data_range: f64,
}

impl Default for SsimParams {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            k1: 0.01,
            k2: 0.03,
            data_range: DATA_RANGE,
        }
    }
}

/// Per-image data reused across many pairs: the local mean and variance on `rect`.
#[derive(Clone, Debug)]
pub struct SsimPrep {
    pub rect: Rect,
    offset: f32,
    /// Gaussian mean of (x - offset) on `rect`.
    mean_c: Vec<f32>,
    /// Gaussian variance on `rect`.
    var: Vec<f32>,
}

#[derive(Clone, Debug)]
pub struct Ssim {
    radius: usize,
    kernel: Vec<f32>,
    c1: f32,
    c2: f32,
}

impl Default for Ssim {
    fn default() -> Self {
        Self::new(SsimParams::default()).expect("default SSIM parameters are valid")
    }
}

impl Ssim {
    pub fn new(p: SsimParams) -> Result<Self, MetricsError> {
        if !(p.sigma > 0.0 && p.sigma < 100.0) {
            return Err(MetricsError::param(
                "sigma",
                format!("{} not in (0, 100)", p.sigma),
            ));
        }
        if !(p.data_range > 0.0 && p.data_range.is_finite()) {
            return Err(MetricsError::param(
                "data_range",
                format!("{} must be positive", p.data_range),
            ));
        }
        // Radius exactly as scipy.ndimage derives it from truncate = 3.5.
        let radius = (3.5 * p.sigma + 0.5) as usize;
        let w: Vec<f64> = (0..=2 * radius)
            .map(|i| {
                let x = i as f64 - radius as f64;
                (-0.5 * x * x / (p.sigma * p.sigma)).exp()
            })
            .collect();
        let sum: f64 = w.iter().sum();
        Ok(Self {
            radius,
            kernel: w.iter().map(|v| (v / sum) as f32).collect(),
            c1: ((p.k1 * p.data_range).powi(2)) as f32,
            c2: ((p.k2 * p.data_range).powi(2)) as f32,
        })
    }

    /// Window side length (11 for sigma 1.5).
    pub fn win_size(&self) -> usize {
        2 * self.radius + 1
    }

    /// Mean SSIM over the image minus a border of (win - 1) / 2, exactly as scikit-image.
    pub fn mean(&self, a: &GrayImage, b: &GrayImage) -> Result<f64, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        let r = self.radius;
        if a.width < self.win_size() || a.height < self.win_size() {
            return Err(MetricsError::TooSmall {
                what: "image pair".into(),
                metric: "SSIM",
                size: a.size(),
                min: self.win_size(),
            });
        }
        let rect = Rect {
            x0: r,
            y0: r,
            x1: a.width - r,
            y1: a.height - r,
        };
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        Ok(self.mean_prepared(a, &pa, b, &pb, None))
    }

    /// Mean of the SSIM map, computed over the whole image (neighbours outside the mask
    /// take part in each window), averaged over the mask pixels. With a mask that is all
    /// set except a (win - 1) / 2 border this equals [`Ssim::mean`].
    pub fn mean_masked(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        mask: &Mask,
    ) -> Result<f64, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        if mask.size() != a.size() {
            return Err(MetricsError::SizeMismatch {
                a: "image".into(),
                a_size: a.size(),
                b: "mask".into(),
                b_size: mask.size(),
            });
        }
        let rect = mask.bbox().ok_or_else(|| MetricsError::EmptyMask {
            what: "SSIM mask".into(),
        })?;
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        Ok(self.mean_prepared(a, &pa, b, &pb, Some(mask)))
    }

    /// The full SSIM map (same size as the images), as scikit-image's `full=True`.
    pub fn map(&self, a: &GrayImage, b: &GrayImage) -> Result<Vec<f32>, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        let rect = Rect::full(a.width, a.height);
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        Ok(self.ssim_rows(a, &pa, b, &pb, CopyRow).concat())
    }

    /// Local mean and variance of `img` on `rect` (the rest of the image still feeds the
    /// windows). Compute once per image, then pair it with many others.
    pub fn prepare(&self, img: &GrayImage, rect: Rect) -> SsimPrep {
        let offset = offset_of(img, rect);
        let (width, height) = (img.width, img.height);
        let (mean_c, mut var) = rayon::join(
            || {
                let src = Centred { img, offset };
                self.blur_rows(&src, width, height, rect, &CopyRow).concat()
            },
            || {
                let src = CentredSquare { img, offset };
                self.blur_rows(&src, width, height, rect, &CopyRow).concat()
            },
        );
        for (v, m) in var.iter_mut().zip(&mean_c) {
            *v -= m * m;
        }
        SsimPrep {
            rect,
            offset,
            mean_c,
            var,
        }
    }

    /// Mean SSIM on `pa.rect` (all of it, or the mask pixels in it). Both preps must
    /// share the rect and come from `a` and `b`.
    ///
    /// The sum runs in f64 along each row and then over the rows in order, so the
    /// result does not depend on the number of threads.
    pub fn mean_prepared(
        &self,
        a: &GrayImage,
        pa: &SsimPrep,
        b: &GrayImage,
        pb: &SsimPrep,
        mask: Option<&Mask>,
    ) -> f64 {
        self.sums_prepared(a, pa, b, pb, mask, false).0
    }

    /// [`Ssim::mean_prepared`] and the mean absolute error on the same pixels (those of
    /// `pa.rect`, or the mask pixels in it) from one pass over the images: the MAE reads
    /// each row while the SSIM pass still has it in cache. The MAE equals
    /// [`super::mae()`] over those pixels to rounding (its sum runs in another order).
    pub fn mean_and_mae_prepared(
        &self,
        a: &GrayImage,
        pa: &SsimPrep,
        b: &GrayImage,
        pb: &SsimPrep,
        mask: Option<&Mask>,
    ) -> (f64, f64) {
        self.sums_prepared(a, pa, b, pb, mask, true)
    }

    fn sums_prepared(
        &self,
        a: &GrayImage,
        pa: &SsimPrep,
        b: &GrayImage,
        pb: &SsimPrep,
        mask: Option<&Mask>,
        with_mae: bool,
    ) -> (f64, f64) {
        let rows = self.ssim_rows(
            a,
            pa,
            b,
            pb,
            MaskedSum {
                mask,
                rect: pa.rect,
                mae: with_mae.then_some((a, b)),
            },
        );
        let (ssim, mae, n) = rows.iter().fold((0.0, 0.0, 0), |acc, r| {
            (acc.0 + r.ssim, acc.1 + r.mae, acc.2 + r.n)
        });
        if n == 0 {
            (f64::NAN, f64::NAN)
        } else {
            let mae = if with_mae { mae / n as f64 } else { f64::NAN };
            (ssim / n as f64, mae)
        }
    }

    /// `then` of each row of `pa.rect` turned into SSIM values, in order: the blurred
    /// cross term is made a strip of rows at a time and turned into SSIM values at once,
    /// never as a whole-rect buffer.
    fn ssim_rows<K: RowSink>(
        &self,
        a: &GrayImage,
        pa: &SsimPrep,
        b: &GrayImage,
        pb: &SsimPrep,
        then: K,
    ) -> Vec<K::Out> {
        assert_eq!(pa.rect, pb.rect, "SSIM preps must share their rect");
        let src = CentredProduct {
            a,
            oa: pa.offset,
            b,
            ob: pb.offset,
        };
        let sink = SsimOf {
            pa,
            pb,
            c1: self.c1,
            c2: self.c2,
            then,
        };
        self.blur_rows(&src, a.width, a.height, pa.rect, &sink)
    }

    /// Separable Gaussian filter of `src` evaluated on `rect` only, with scipy's
    /// "reflect" boundary (d c b a | a b c d | d c b a) at the image edges:
    /// `sink.row(row index in the rect, filtered row)` for each row of the rect, in
    /// order. Strips of rows run in parallel; each keeps the last `2 * radius + 1` rows
    /// of its horizontal pass in a ring (tens of KiB), so no pass writes a whole-rect
    /// buffer.
    fn blur_rows<S: RowSource, K: RowSink>(
        &self,
        src: &S,
        width: usize,
        height: usize,
        rect: Rect,
        sink: &K,
    ) -> Vec<K::Out> {
        let h = rect.height();
        // A few strips per thread; each strip pays 2 * radius extra horizontal rows.
        let strip = h
            .div_ceil(4 * rayon::current_num_threads())
            .max(8 * self.win_size())
            .max(1);
        let strips: Vec<std::ops::Range<usize>> = (0..h)
            .step_by(strip)
            .map(|s| s..(s + strip).min(h))
            .collect();
        let done: Vec<Vec<K::Out>> = strips
            .into_par_iter()
            .map(|rows| {
                let strip = Strip {
                    kernel: &self.kernel,
                    width,
                    height,
                    rect,
                    rows,
                };
                self.blur_strip(strip, src, sink)
            })
            .collect();
        done.into_iter().flatten().collect()
    }

    /// One strip of [`Ssim::blur_rows`], on the widest SIMD this CPU has (the same sums
    /// in the same order at any width: the results are the same bits).
    fn blur_strip<S: RowSource, K: RowSink>(&self, strip: Strip, src: &S, sink: &K) -> Vec<K::Out> {
        #[cfg(target_arch = "x86_64")]
        if simd_wide() {
            // SAFETY: the CPU has AVX2 (checked at run time just above).
            return unsafe { blur_strip_avx2(strip, src, sink) };
        }
        blur_strip_core(strip, src, sink)
    }
}

/// The SSIM of one pixel from its means, variances and covariance. f32 is enough here:
/// the terms are sums of positives or already-centred moments, and per-pixel rounding
/// averages out in the mean (tests: within 1e-7 of skimage).
#[inline(always)]
fn ssim_of(mx: f32, my: f32, vx: f32, vy: f32, cov: f32, c1: f32, c2: f32) -> f32 {
    let a1 = 2.0 * mx * my + c1;
    let a2 = 2.0 * cov + c2;
    let b1 = mx * mx + my * my + c1;
    let b2 = vx + vy + c2;
    (a1 * a2) / (b1 * b2)
}

/// One strip of a blur: the kernel, the image's size, the rect the blur is evaluated on
/// and the strip's rows (of the rect).
struct Strip<'a> {
    kernel: &'a [f32],
    width: usize,
    height: usize,
    rect: Rect,
    rows: std::ops::Range<usize>,
}

/// What a blur filters, read a row segment at a time (contiguous, so the loop vectorises).
trait RowSource: Sync {
    /// `out[c]` = the value at column `x0 + c` of row `y`.
    fn fill(&self, y: usize, x0: usize, out: &mut [f32]);
}

/// x - offset.
struct Centred<'a> {
    img: &'a GrayImage,
    offset: f32,
}

/// (x - offset)^2.
struct CentredSquare<'a> {
    img: &'a GrayImage,
    offset: f32,
}

/// (a - oa) (b - ob).
struct CentredProduct<'a> {
    a: &'a GrayImage,
    oa: f32,
    b: &'a GrayImage,
    ob: f32,
}

fn row_of(img: &GrayImage, y: usize, x0: usize, n: usize) -> &[f32] {
    let start = y * img.width + x0;
    &img.data[start..start + n]
}

impl RowSource for Centred<'_> {
    #[inline(always)]
    fn fill(&self, y: usize, x0: usize, out: &mut [f32]) {
        let row = row_of(self.img, y, x0, out.len());
        for (o, &v) in out.iter_mut().zip(row) {
            *o = v - self.offset;
        }
    }
}

impl RowSource for CentredSquare<'_> {
    #[inline(always)]
    fn fill(&self, y: usize, x0: usize, out: &mut [f32]) {
        let row = row_of(self.img, y, x0, out.len());
        for (o, &v) in out.iter_mut().zip(row) {
            let c = v - self.offset;
            *o = c * c;
        }
    }
}

impl RowSource for CentredProduct<'_> {
    #[inline(always)]
    fn fill(&self, y: usize, x0: usize, out: &mut [f32]) {
        let ra = row_of(self.a, y, x0, out.len());
        let rb = row_of(self.b, y, x0, out.len());
        for ((o, &va), &vb) in out.iter_mut().zip(ra).zip(rb) {
            *o = (va - self.oa) * (vb - self.ob);
        }
    }
}

/// Whether this CPU runs the AVX2 build of the blur (checked once).
#[cfg(target_arch = "x86_64")]
fn simd_wide() -> bool {
    static WIDE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *WIDE.get_or_init(|| {
        std::arch::is_x86_feature_detected!("avx2")
            && std::env::var_os("SYNOSIS_METRICS_NO_AVX2").is_none()
    })
}

/// [`blur_strip_core`] compiled for AVX2 (8 f32 lanes instead of SSE2's 4). No FMA: a
/// fused multiply-add would round differently from the portable build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn blur_strip_avx2<S: RowSource, K: RowSink>(strip: Strip, src: &S, sink: &K) -> Vec<K::Out> {
    blur_strip_core(strip, src, sink)
}

/// The rows of a strip of the separable blur: the horizontal pass of each source row once
/// into a ring of `kernel.len()` rows, then the vertical taps of each output row.
/// Every output value is `sum over taps t, in order, of kernel[t] * value`, both passes
/// starting from 0, whatever the SIMD width.
#[inline(always)]
fn blur_strip_core<S: RowSource, K: RowSink>(strip: Strip, src: &S, sink: &K) -> Vec<K::Out> {
    let kernel = strip.kernel;
    let rows = strip.rows.clone();
    let taps = kernel.len();
    let r = taps / 2;
    let rw = strip.rect.width();
    let mut ring = vec![0.0f32; taps * rw];
    let mut pad = vec![0.0f32; rw + 2 * r];
    let mut out = vec![0.0f32; rw];
    let mut done = Vec::with_capacity(rows.len());
    // Where tap t's line starts: in `pad` (horizontal pass) and in `ring` (vertical).
    let pad_starts: Vec<usize> = (0..taps).collect();
    let mut ring_starts = vec![0usize; taps];
    let y_first = (strip.rect.y0 + rows.start) as isize;
    for v in y_first - r as isize..y_first + r as isize {
        horizontal(&strip, &pad_starts, src, v, &mut pad, &mut ring);
    }
    for ry in rows {
        let y = (strip.rect.y0 + ry) as isize;
        horizontal(
            &strip,
            &pad_starts,
            src,
            y + r as isize,
            &mut pad,
            &mut ring,
        );
        for (t, start) in ring_starts.iter_mut().enumerate() {
            *start = (y - r as isize + t as isize).rem_euclid(taps as isize) as usize * rw;
        }
        convolve(kernel, &ring, &ring_starts, &mut out);
        done.push(sink.row(ry, &mut out));
    }
    done
}

/// The horizontal pass of virtual row `v` (reflected into the image) into its slot of
/// `ring` (`v` modulo the taps), through `pad` (the row's columns the rect's windows read,
/// reflected at the image's edges).
#[inline(always)]
fn horizontal<S: RowSource>(
    strip: &Strip,
    pad_starts: &[usize],
    src: &S,
    v: isize,
    pad: &mut [f32],
    ring: &mut [f32],
) {
    let kernel = strip.kernel;
    let taps = kernel.len();
    let r = taps / 2;
    let rw = strip.rect.width();
    let y = reflect(v, strip.height);
    // The columns whose window stays inside the image read one contiguous segment.
    let first = strip.rect.x0 as isize - r as isize;
    let c_lo = ((-first).max(0) as usize).min(pad.len());
    let c_hi = ((strip.width as isize - first).max(0) as usize)
        .min(pad.len())
        .max(c_lo);
    for c in (0..c_lo).chain(c_hi..pad.len()) {
        src.fill(
            y,
            reflect(first + c as isize, strip.width),
            &mut pad[c..c + 1],
        );
    }
    if c_hi > c_lo {
        src.fill(y, (first + c_lo as isize) as usize, &mut pad[c_lo..c_hi]);
    }
    let slot = v.rem_euclid(taps as isize) as usize;
    convolve(
        kernel,
        pad,
        pad_starts,
        &mut ring[slot * rw..(slot + 1) * rw],
    );
}

/// What [`Ssim::blur_rows`] does with each filtered row (inlined into the SIMD build).
trait RowSink: Sync {
    type Out: Send;
    /// `row` is row `ry` of the rect; it may be overwritten.
    fn row(&self, ry: usize, row: &mut [f32]) -> Self::Out;
}

/// The row itself.
struct CopyRow;

impl RowSink for CopyRow {
    type Out = Vec<f32>;
    #[inline(always)]
    fn row(&self, _ry: usize, row: &mut [f32]) -> Vec<f32> {
        row.to_vec()
    }
}

/// A row of the blurred cross term turned into SSIM values (from both preps' means and
/// variances), then handed to `then`.
struct SsimOf<'a, K> {
    pa: &'a SsimPrep,
    pb: &'a SsimPrep,
    c1: f32,
    c2: f32,
    then: K,
}

impl<K: RowSink> RowSink for SsimOf<'_, K> {
    type Out = K::Out;
    #[inline(always)]
    fn row(&self, ry: usize, row: &mut [f32]) -> K::Out {
        let rw = row.len();
        let at = ry * rw..(ry + 1) * rw;
        let (pa, pb) = (self.pa, self.pb);
        let (ma, mb) = (&pa.mean_c[at.clone()], &pb.mean_c[at.clone()]);
        let (va, vb) = (&pa.var[at.clone()], &pb.var[at]);
        for x in 0..rw {
            let cov = row[x] - ma[x] * mb[x];
            row[x] = ssim_of(
                ma[x] + pa.offset,
                mb[x] + pb.offset,
                va[x],
                vb[x],
                cov,
                self.c1,
                self.c2,
            );
        }
        self.then.row(ry, row)
    }
}

/// The sum of a row's values (those under the mask, if any) in f64 and their count, and,
/// with `mae`, the sum of |a - b| over the same pixels of the row. Four partial sums
/// (columns modulo 4), added at the end of the row: the same bits at any SIMD width.
struct MaskedSum<'a> {
    mask: Option<&'a Mask>,
    rect: Rect,
    mae: Option<(&'a GrayImage, &'a GrayImage)>,
}

/// One row's sums from [`MaskedSum`].
struct RowSums {
    ssim: f64,
    mae: f64,
    n: usize,
}

impl RowSink for MaskedSum<'_> {
    type Out = RowSums;
    #[inline(always)]
    fn row(&self, ry: usize, row: &mut [f32]) -> RowSums {
        let rw = row.len();
        let y = self.rect.y0 + ry;
        let (n, keep) = match self.mask {
            Some(m) => {
                let start = y * m.width + self.rect.x0;
                let keep = &m.data[start..start + rw];
                (keep.iter().filter(|&&k| k).count(), Some(keep))
            }
            None => (rw, None),
        };
        let ssim = sum4(keep, row);
        let mae = match self.mae {
            Some((a, b)) => {
                let (ra, rb) = (
                    row_of(a, y, self.rect.x0, rw),
                    row_of(b, y, self.rect.x0, rw),
                );
                // The SSIM row is summed: its buffer takes the differences.
                for ((d, &va), &vb) in row.iter_mut().zip(ra).zip(rb) {
                    *d = (va - vb).abs();
                }
                sum4(keep, row)
            }
            None => 0.0,
        };
        RowSums { ssim, mae, n }
    }
}

/// `(s0 + s1) + (s2 + s3)`, where `s_j` is the f64 sum of `values[x]` over the kept
/// columns x = j, j + 4, ... (`s0` also takes the last `len % 4` columns), each in order;
/// `keep` is the mask's row (every column kept if `None`).
#[inline(always)]
fn sum4(keep: Option<&[bool]>, values: &[f32]) -> f64 {
    const P: usize = 4;
    let mut s = [0.0f64; P];
    let chunks = values.chunks_exact(P);
    let rest = chunks.remainder();
    match keep {
        Some(k) => {
            let keep_chunks = k.chunks_exact(P);
            let keep_rest = keep_chunks.remainder();
            for (v, k) in chunks.zip(keep_chunks) {
                for l in 0..P {
                    // A masked-out value's bits cleared (+0.0, whatever the value, NaN
                    // included): the same sum as skipping it, and it vectorises.
                    let bits = f64::from(v[l]).to_bits() & 0u64.wrapping_sub(u64::from(k[l]));
                    s[l] += f64::from_bits(bits);
                }
            }
            for (&v, &k) in rest.iter().zip(keep_rest) {
                s[0] += if k { f64::from(v) } else { 0.0 };
            }
        }
        None => {
            for v in chunks {
                for l in 0..P {
                    s[l] += f64::from(v[l]);
                }
            }
            for &v in rest {
                s[0] += f64::from(v);
            }
        }
    }
    (s[0] + s[1]) + (s[2] + s[3])
}

/// `out[x] = sum over t of kernel[t] * lines[starts[t] + x]`, t in order from 0. Four
/// blocks of eight columns at a time are held in registers (four independent chains of
/// additions), then single blocks, then single columns: the same sums in the same order
/// for every column.
#[inline(always)]
fn convolve(kernel: &[f32], lines: &[f32], starts: &[usize], out: &mut [f32]) {
    const L: usize = 8;
    const B: usize = 4;
    let n = out.len();
    let mut x = 0;
    while x + B * L <= n {
        let mut acc = [[0.0f32; L]; B];
        for (&w, &s0) in kernel.iter().zip(starts) {
            let s: &[f32; B * L] = lines[s0 + x..s0 + x + B * L]
                .try_into()
                .expect("four blocks of eight columns");
            for b in 0..B {
                for l in 0..L {
                    acc[b][l] += w * s[b * L + l];
                }
            }
        }
        for b in 0..B {
            out[x + b * L..x + (b + 1) * L].copy_from_slice(&acc[b]);
        }
        x += B * L;
    }
    while x + L <= n {
        let mut acc = [0.0f32; L];
        for (&w, &s0) in kernel.iter().zip(starts) {
            let s: &[f32; L] = lines[s0 + x..s0 + x + L].try_into().expect("eight columns");
            for l in 0..L {
                acc[l] += w * s[l];
            }
        }
        out[x..x + L].copy_from_slice(&acc);
        x += L;
    }
    for (x, o) in out.iter_mut().enumerate().skip(x) {
        let mut acc = 0.0f32;
        for (&w, &s0) in kernel.iter().zip(starts) {
            acc += w * lines[s0 + x];
        }
        *o = acc;
    }
}

fn offset_of(img: &GrayImage, rect: Rect) -> f32 {
    let mut s = 0.0f64;
    for y in rect.y0..rect.y1 {
        s += img.data[y * img.width + rect.x0..y * img.width + rect.x1]
            .iter()
            .map(|&v| f64::from(v))
            .sum::<f64>();
    }
    (s / (rect.width() * rect.height()).max(1) as f64) as f32
}

/// scipy.ndimage "reflect" index, valid for any offset (repeats with period 2n).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let m = i.rem_euclid(2 * n);
    (if m >= n { 2 * n - 1 - m } else { m }) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflect_matches_scipy() {
        let got: Vec<usize> = (-4..8).map(|i| reflect(i, 4)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0]);
        assert_eq!(reflect(-3, 2), 1);
    }

    #[test]
    fn kernel_has_eleven_taps_summing_to_one() {
        let s = Ssim::default();
        assert_eq!(s.win_size(), 11);
        let sum: f32 = s.kernel.iter().sum();
        assert!((sum - 1.0).abs() < 1e-6);
        assert!(s.kernel[5] > s.kernel[4] && (s.kernel[0] - s.kernel[10]).abs() < 1e-9);
    }

    /// A textured test image: smooth gradients plus a hash for fine detail, 0..255.
    fn image(width: usize, height: usize, seed: u32) -> GrayImage {
        let data = (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as f32, (i / width) as f32);
                let h = (i as u32 ^ seed)
                    .wrapping_mul(2_654_435_761)
                    .rotate_left(13)
                    .wrapping_mul(40_503);
                let noise = (h >> 24) as f32 / 255.0;
                (100.0 + 60.0 * (0.13 * x + 0.07 * y).sin() + 90.0 * noise - 45.0).clamp(0.0, 255.0)
            })
            .collect();
        GrayImage::new(width, height, data).unwrap()
    }

    /// The blur against a direct 2-D sum in f64 with reflected indices, on an odd-sized
    /// image and a rect that touches the top and right edges but not the others (so
    /// windows read reflected columns and rows as well as the contiguous segment).
    #[test]
    fn blur_matches_a_direct_reflected_sum() {
        let s = Ssim::default();
        let (img, tiny) = (image(37, 23, 7), image(3, 2, 8));
        let rect = Rect {
            x0: 3,
            y0: 0,
            x1: 37,
            y1: 19,
        };
        // The tiny image is narrower than the window's radius: every window reflects
        // several times.
        for (img, rect) in [(&img, rect), (&tiny, Rect::full(3, 2))] {
            let src = Centred { img, offset: 0.0 };
            let got = s
                .blur_rows(&src, img.width, img.height, rect, &CopyRow)
                .concat();
            let k: Vec<f64> = s.kernel.iter().map(|&w| f64::from(w)).collect();
            let r = s.radius as isize;
            let mut worst = 0.0f64;
            for y in rect.y0..rect.y1 {
                for x in rect.x0..rect.x1 {
                    let mut want = 0.0f64;
                    for dy in -r..=r {
                        for dx in -r..=r {
                            let sy = reflect(y as isize + dy, img.height);
                            let sx = reflect(x as isize + dx, img.width);
                            want += k[(dy + r) as usize]
                                * k[(dx + r) as usize]
                                * f64::from(img.data[sy * img.width + sx]);
                        }
                    }
                    let g = f64::from(got[(y - rect.y0) * rect.width() + (x - rect.x0)]);
                    worst = worst.max((g - want).abs());
                }
            }
            assert_eq!(got.len(), rect.width() * rect.height());
            assert!(
                worst < 1e-3,
                "{} x {}: largest difference {worst} (values up to 255)",
                img.width,
                img.height
            );
        }
    }

    /// The AVX2 build and the portable one give the same bits (on a CPU without AVX2 there
    /// is only the portable one, and nothing to compare).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_blur_equals_portable_bits() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: one build only");
            return;
        }
        let s = Ssim::default();
        let (a, b) = (image(53, 41, 1), image(53, 41, 2));
        let rect = Rect {
            x0: 2,
            y0: 5,
            x1: 50,
            y1: 41,
        };
        let src = CentredProduct {
            a: &a,
            oa: 120.0,
            b: &b,
            ob: 97.5,
        };
        let strip = || Strip {
            kernel: &s.kernel,
            width: a.width,
            height: a.height,
            rect,
            rows: 0..rect.height(),
        };
        let portable = blur_strip_core(strip(), &src, &CopyRow);
        // SAFETY: AVX2 checked above.
        let wide = unsafe { blur_strip_avx2(strip(), &src, &CopyRow) };
        let bits =
            |v: &Vec<Vec<f32>>| -> Vec<u32> { v.concat().iter().map(|f| f.to_bits()).collect() };
        assert_eq!(bits(&portable), bits(&wide));
    }

    /// The MAE made beside the SSIM equals the MAE alone on the mask's pixels (to
    /// rounding: its sum runs in another order), and the SSIM is the same bits.
    #[test]
    fn mae_beside_ssim_equals_mae_alone() {
        let s = Ssim::default();
        let (a, b) = (image(97, 83, 5), image(97, 83, 6));
        let mut mask = Mask::filled(a.width, a.height, false);
        mask.fill_polygon(&[[3.0, 70.0], [90.0, 8.0], [95.0, 80.0]]);
        let rect = mask.bbox().unwrap();
        let (pa, pb) = (s.prepare(&a, rect), s.prepare(&b, rect));
        let (ssim, mae) = s.mean_and_mae_prepared(&a, &pa, &b, &pb, Some(&mask));
        let alone = super::super::mae(&a, &b, Some(&mask.indices()));
        assert!(
            (mae - alone).abs() <= 1e-12 * alone,
            "{mae} against {alone}"
        );
        let ssim_alone = s.mean_prepared(&a, &pa, &b, &pb, Some(&mask));
        assert_eq!(ssim.to_bits(), ssim_alone.to_bits());
        // Without a mask: every pixel of the rect.
        let full = Rect::full(a.width, a.height);
        let (fa, fb) = (s.prepare(&a, full), s.prepare(&b, full));
        let (_, mae_all) = s.mean_and_mae_prepared(&a, &fa, &b, &fb, None);
        let alone_all = super::super::mae(&a, &b, None);
        assert!((mae_all - alone_all).abs() <= 1e-12 * alone_all);
        assert!(mae > 10.0 && mae_all > 10.0, "{mae} {mae_all}");
        // A pixel outside the mask does not reach the MAE, whatever its value.
        let mut b_nan = b.clone();
        assert!(!mask.data[15 * b.width + 10]);
        b_nan.data[15 * b.width + 10] = f32::NAN;
        let (_, mae_nan) = s.mean_and_mae_prepared(&a, &pa, &b_nan, &pb, Some(&mask));
        assert_eq!(mae_nan.to_bits(), mae.to_bits());
    }

    /// The mean SSIM is the same bits on one thread and on three (strips, rows summed in
    /// order), masked and not.
    #[test]
    fn mean_does_not_depend_on_threads() {
        let s = Ssim::default();
        let (a, b) = (image(203, 171, 3), image(203, 171, 4));
        let mut mask = Mask::filled(a.width, a.height, false);
        mask.fill_polygon(&[[20.0, 15.0], [190.0, 40.0], [120.0, 160.0], [10.0, 120.0]]);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                (
                    s.mean(&a, &b).unwrap(),
                    s.mean_masked(&a, &b, &mask).unwrap(),
                )
            })
        };
        let (one, three) = (run(1), run(3));
        assert_eq!(one.0.to_bits(), three.0.to_bits());
        assert_eq!(one.1.to_bits(), three.1.to_bits());
        assert!(
            one.0 > 0.0 && one.0 < 1.0 && one.1 > 0.0 && one.1 < 1.0,
            "{one:?}"
        );
    }
}
