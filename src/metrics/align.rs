//! Linear intensity alignment of synthetic images to real ones (paper, "A posteriori
//! quality"): `factor * v + bias`, clamped to 0..=255.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alignment {
    pub factor: f32,
    pub bias: f32,
}

impl Alignment {
    pub const IDENTITY: Alignment = Alignment {
        factor: 1.0,
        bias: 0.0,
    };

    #[inline]
    pub fn apply(self, v: f32) -> f32 {
        (self.factor * v + self.bias).clamp(0.0, 255.0)
    }

    /// Moment matching: the affine map that gives the synthetic pixels the real pixels'
    /// mean and standard deviation. Between unpaired images this is the least-squares
    /// fit of one distribution onto the other up to shape; clamping is ignored.
    /// `None` when the synthetic side is constant or either side is empty.
    pub fn fit(real: &Moments, synthetic: &Moments) -> Option<Alignment> {
        let (mr, sr) = real.mean_std()?;
        let (ms, ss) = synthetic.mean_std()?;
        if ss <= 0.0 {
            return None;
        }
        let factor = sr / ss;
        Some(Alignment {
            factor: factor as f32,
            bias: (mr - factor * ms) as f32,
        })
    }
}

/// The paper's manually estimated (factor, bias) per texture type.
pub fn paper_defaults() -> BTreeMap<String, Alignment> {
    [
        ("sandblasted", 0.632, 34.0),
        ("parallel", 1.481, 39.0),
        ("spiral", 1.526, 33.0),
    ]
    .into_iter()
    .map(|(t, factor, bias)| (t.to_string(), Alignment { factor, bias }))
    .collect()
}

/// Running first and second moments of pixel values (f64; sums of up to ~10^10 values).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Moments {
    pub n: u64,
    pub sum: f64,
    pub sum_sq: f64,
}

impl Moments {
    pub fn add(&mut self, v: f32) {
        let v = f64::from(v);
        self.n += 1;
        self.sum += v;
        self.sum_sq += v * v;
    }

    pub fn merge(mut self, o: Moments) -> Moments {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        self
    }

    pub fn mean_std(&self) -> Option<(f64, f64)> {
        if self.n == 0 {
            return None;
        }
        let mean = self.sum / self.n as f64;
        let var = (self.sum_sq / self.n as f64 - mean * mean).max(0.0);
        Some((mean, var.sqrt()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_recovers_an_affine_map() {
        let (mut r, mut s) = (Moments::default(), Moments::default());
        for v in [3.0f32, 10.0, 50.0, 80.0, 81.0] {
            s.add(v);
            r.add(1.5 * v + 20.0);
        }
        let a = Alignment::fit(&r, &s).unwrap();
        assert!(
            (a.factor - 1.5).abs() < 1e-5 && (a.bias - 20.0).abs() < 1e-3,
            "{a:?}"
        );
        assert!(Alignment::fit(&r, &Moments::default()).is_none());
    }

    #[test]
    fn apply_clamps() {
        let a = Alignment {
            factor: 2.0,
            bias: 10.0,
        };
        assert_eq!(a.apply(100.0), 210.0);
        assert_eq!(a.apply(200.0), 255.0);
        assert_eq!(
            Alignment {
                factor: 1.0,
                bias: -5.0
            }
            .apply(2.0),
            0.0
        );
    }
}
