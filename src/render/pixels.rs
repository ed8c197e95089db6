//! Radiance to pixel values: the one pixel pipeline of `synosis render` and the dataset.
//!
//! Model (linear exposure, no noise, no response curve, no vignetting; see
//! docs/rendering.md, "Sensor"): a pixel's fraction of full scale is
//! `v = clamp(L * scale, 0, 1)` for linear radiance `L`, `scale = exposure * gain`,
//! and NaN becomes 0. An image file stores `round(v * (2^bits - 1))`, rounding half
//! away from zero, for 8 or 16 bits ([`Exposure::quantise8`], [`Exposure::quantise16`]).
//!
//! Post-processing (the dataset's `[[postprocess]]` steps) works between the two halves,
//! on an f32 image in **8-bit units**, unclamped: `FULL_SCALE * scale * L`
//! ([`Exposure::units8`]); [`quantise_units8`] then clamps to [0, 255] and rounds.
//! Both routes are the same model; they are evaluated in the order each used before
//! this module existed (`(L * scale) * 255` against `L * (255 * scale)`), so for the
//! same radiance the two can differ by one code value where the product lands within
//! float rounding of a half-way point. They are kept apart so every image stays bit for
//! bit what it was.
//!
//! Next: the camera issue replaces [`Exposure`] by an EMVA 1288 sensor (quantum
//! efficiency, shot and dark noise, full-well clipping, ADC gain and bit depth) with
//! the same two outputs, codes for a file and an 8-bit-unit image for post-processing.

/// Full scale of the 8-bit-unit image post-processing works on.
pub const FULL_SCALE: f32 = 255.0;

/// The linear exposure model: radiance times `scale` is the fraction of full scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    /// Radiance -> fraction of full scale; `exposure * gain` (unit: 1 / radiance unit).
    pub scale: f32,
}

impl Exposure {
    /// `scale = exposure * gain`.
    pub fn new(exposure: f32, gain: f32) -> Self {
        Exposure {
            scale: exposure * gain,
        }
    }

    /// Fraction of full scale of one pixel, in [0, 1]; NaN gives 0.
    pub fn fraction(self, radiance: f32) -> f32 {
        let v = radiance * self.scale;
        if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }
    }

    /// 8-bit codes, `round(fraction * 255)`.
    pub fn quantise8(self, radiance: &[f32]) -> Vec<u8> {
        radiance
            .iter()
            .map(|&r| (self.fraction(r) * 255.0).round() as u8)
            .collect()
    }

    /// 16-bit codes, `round(fraction * 65535)`.
    pub fn quantise16(self, radiance: &[f32]) -> Vec<u16> {
        radiance
            .iter()
            .map(|&r| (self.fraction(r) * 65535.0).round() as u16)
            .collect()
    }

    /// The image post-processing works on: `FULL_SCALE * scale * L` in 8-bit units,
    /// not clamped (NaN stays NaN until [`quantise_units8`]).
    pub fn units8(self, radiance: &[f32]) -> Vec<f32> {
        let k = FULL_SCALE * self.scale;
        radiance.iter().map(|&l| k * l).collect()
    }
}

/// An 8-bit-unit image to 8-bit codes: NaN gives 0, then clamp to [0, 255] and round.
pub fn quantise_units8(image: &[f32]) -> Vec<u8> {
    image
        .iter()
        .map(|&v| {
            if v.is_nan() {
                0
            } else {
                v.clamp(0.0, FULL_SCALE).round() as u8
            }
        })
        .collect()
}

/// An 8-bit-unit image to the codes of a `bit_depth`-bit sensor (10, 12 or 16; written
/// to a 16-bit PNG unscaled, as `synosis render` does): NaN gives 0, then
/// `round(v * (2^bit_depth - 1) / 255)` clamped to [0, 2^bit_depth - 1]. The inverse of
/// the sensor step's `code * 255 / (2^bit_depth - 1)`, exact for every code.
pub fn quantise_units_deep(image: &[f32], bit_depth: u32) -> Vec<u16> {
    let top = ((1u64 << bit_depth.clamp(1, 16)) - 1) as f64;
    image
        .iter()
        .map(|&v| {
            if v.is_nan() {
                0
            } else {
                (v as f64 * top / FULL_SCALE as f64).clamp(0.0, top).round() as u16
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deep_codes_survive_the_8_bit_unit_scale() {
        for bits in [10u32, 12, 16] {
            let top = (1u32 << bits) - 1;
            let scale = (FULL_SCALE as f64 / top as f64) as f32;
            let codes: Vec<u16> = (0..=top).map(|c| c as u16).collect();
            let units: Vec<f32> = codes.iter().map(|&c| c as f32 * scale).collect();
            assert_eq!(quantise_units_deep(&units, bits), codes, "{bits} bit");
        }
        let q = quantise_units_deep(&[f32::NAN, -3.0, 300.0, 127.5], 12);
        assert_eq!(q, vec![0, 0, 4095, 2048]);
    }

    /// `render/sensor.rs` as it was (the `synosis render` route).
    fn old_sensor8(radiance: &[f32], exposure: f32, gain: f32) -> Vec<u8> {
        let s = exposure * gain;
        radiance
            .iter()
            .map(|&r| {
                let v = r * s;
                let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
                (v * 255.0).round() as u8
            })
            .collect()
    }

    fn old_sensor16(radiance: &[f32], exposure: f32, gain: f32) -> Vec<u16> {
        let s = exposure * gain;
        radiance
            .iter()
            .map(|&r| {
                let v = r * s;
                let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
                (v * 65535.0).round() as u16
            })
            .collect()
    }

    /// `dataset/runner.rs` + `post::quantize` as they were (the dataset route, no steps).
    fn old_dataset8(radiance: &[f32], exposure: f64) -> Vec<u8> {
        let scale = 255.0f32 * exposure as f32;
        radiance
            .iter()
            .map(|&l| {
                let v = scale * l;
                if v.is_nan() {
                    0
                } else {
                    v.clamp(0.0, 255.0).round() as u8
                }
            })
            .collect()
    }

    /// NaN, infinities, negatives, zero, above full scale, exact and near half-way
    /// points of both depths, and a sweep.
    fn edge_values() -> Vec<f32> {
        let mut v = vec![
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1.0,
            -0.0,
            0.0,
            f32::MIN_POSITIVE,
            1.0,
            1.5,
            1e30,
        ];
        for k in 0..256 {
            let half = (k as f32 + 0.5) / 255.0;
            v.extend([half, half.next_up(), half.next_down()]);
        }
        for k in [0u32, 1, 2, 32767, 65533, 65534] {
            let half = (k as f32 + 0.5) / 65535.0;
            v.extend([half, half.next_up(), half.next_down()]);
        }
        v.extend((0..4000).map(|i| i as f32 * 3.1e-4 - 0.05));
        v
    }

    #[test]
    fn the_render_route_gives_the_old_sensor_codes() {
        let r = edge_values();
        for (e, g) in [(1.0, 1.0), (2.0, 1.0), (0.37, 1.9), (1e-3, 250.0)] {
            let x = Exposure::new(e, g);
            assert_eq!(
                x.quantise8(&r),
                old_sensor8(&r, e, g),
                "exposure {e} gain {g}"
            );
            assert_eq!(
                x.quantise16(&r),
                old_sensor16(&r, e, g),
                "exposure {e} gain {g}"
            );
        }
    }

    #[test]
    fn the_dataset_route_gives_the_old_dataset_codes() {
        let r = edge_values();
        // Half-way points in 8-bit units too.
        let mut r2: Vec<f32> = (0..256).map(|k| (k as f32 + 0.5) / 255.0).collect();
        r2.extend(&r);
        for e in [1.0f64, 0.5, 2.0, 0.123_456_789, 3.0e-3] {
            let x = Exposure::new(e as f32, 1.0);
            assert_eq!(quantise_units8(&x.units8(&r2)), old_dataset8(&r2, e), "{e}");
        }
    }

    #[test]
    fn edge_values_map_as_documented() {
        let x = Exposure::new(2.0, 1.0);
        assert_eq!(
            x.quantise8(&[-1.0, 0.0, 0.25, 0.5, 10.0, f32::NAN]),
            [0, 0, 128, 255, 255, 0]
        );
        assert_eq!(
            x.quantise16(&[0.25, f32::INFINITY, -0.0]),
            [32768, 65535, 0]
        );
        assert_eq!(
            quantise_units8(&[-3.0, 0.49, 0.5, 254.5, 254.6, 300.0, f32::NAN]),
            [0, 0, 1, 255, 255, 255, 0]
        );
        // Post-processing sees the unclamped value.
        assert_eq!(x.units8(&[1.0, -1.0]), [510.0, -510.0]);
    }
}
