//! The sensor model: linear radiance to pixel values.
//!
//! value = clamp(radiance * exposure * gain, 0, 1), then quantised to the nearest of
//! 2^bits - 1 levels. No noise, no response curve, no vignetting (docs/rendering.md).

/// Normalised sensor values in [0, 1]; NaN becomes 0.
pub fn normalise(radiance: &[f32], exposure: f32, gain: f32) -> Vec<f32> {
    let s = exposure * gain;
    radiance
        .iter()
        .map(|&r| {
            let v = r * s;
            if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }
        })
        .collect()
}

pub fn quantise8(radiance: &[f32], exposure: f32, gain: f32) -> Vec<u8> {
    normalise(radiance, exposure, gain)
        .iter()
        .map(|v| (v * 255.0).round() as u8)
        .collect()
}

pub fn quantise16(radiance: &[f32], exposure: f32, gain: f32) -> Vec<u16> {
    normalise(radiance, exposure, gain)
        .iter()
        .map(|v| (v * 65535.0).round() as u16)
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn clips_and_quantises() {
        let v = super::quantise8(&[-1.0, 0.0, 0.25, 0.5, 10.0, f32::NAN], 2.0, 1.0);
        assert_eq!(v, vec![0, 0, 128, 255, 255, 0]);
    }
}
