//! Boolean pixel masks: loading, face-id selection, polygon filling, intersection.

use std::path::Path;

use image::DynamicImage;

use super::MetricsError;

/// Half-open pixel rectangle `[x0, x1) x [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

impl Rect {
    pub fn full(width: usize, height: usize) -> Self {
        Self {
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
        }
    }

    pub fn width(&self) -> usize {
        self.x1 - self.x0
    }

    pub fn height(&self) -> usize {
        self.y1 - self.y0
    }

    pub fn is_empty(&self) -> bool {
        self.x1 <= self.x0 || self.y1 <= self.y0
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    pub width: usize,
    pub height: usize,
    pub data: Vec<bool>,
}

impl Mask {
    pub fn filled(width: usize, height: usize, value: bool) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Any grayscale PNG; a pixel is inside where its value is non-zero.
    pub fn load(path: &Path) -> Result<Self, MetricsError> {
        // The same decoding as images (8/16-bit, alpha ignored, others refused); 16-bit
        // values are scaled by 1/257, which keeps every non-zero value non-zero.
        let img = super::gray::GrayImage::load(path)?;
        Ok(Self {
            width: img.width,
            height: img.height,
            data: img.data.iter().map(|&v| v != 0.0).collect(),
        })
    }

    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }

    pub fn and_assign(&mut self, other: &Mask) {
        for (a, &b) in self.data.iter_mut().zip(&other.data) {
            *a &= b;
        }
    }

    pub fn or_assign(&mut self, other: &Mask) {
        for (a, &b) in self.data.iter_mut().zip(&other.data) {
            *a |= b;
        }
    }

    /// Bounding box of the set pixels, `None` for an empty mask.
    pub fn bbox(&self) -> Option<Rect> {
        let mut r = Rect {
            x0: usize::MAX,
            y0: usize::MAX,
            x1: 0,
            y1: 0,
        };
        for y in 0..self.height {
            let row = &self.data[y * self.width..(y + 1) * self.width];
            if let (Some(first), Some(last)) =
                (row.iter().position(|&b| b), row.iter().rposition(|&b| b))
            {
                r.x0 = r.x0.min(first);
                r.x1 = r.x1.max(last + 1);
                r.y0 = r.y0.min(y);
                r.y1 = y + 1;
            }
        }
        (r.x1 > 0).then_some(r)
    }

    /// Linear indices of the set pixels, ascending.
    pub fn indices(&self) -> Vec<u32> {
        self.data
            .iter()
            .enumerate()
            .filter(|(_, b)| **b)
            .map(|(i, _)| i as u32)
            .collect()
    }

    /// Fills a polygon (even-odd rule) into the mask. Pixel centres sit at integer
    /// coordinates, as in LabelMe's own rasterisation (PIL); pixels whose centres lie
    /// exactly on an edge are filled too (PIL draws the outline), so a polygon through
    /// pixel centres (as `synosis dataset` writes them) gives back its pixels exactly. For
    /// other polygons, pixels near the boundary may differ from PIL's by one (PIL's
    /// outline of a slanted edge), which the meta-mask intersection absorbs.
    pub fn fill_polygon(&mut self, points: &[[f64; 2]]) {
        if points.len() < 3 {
            return;
        }
        // Pixel centres on an edge.
        for (i, a) in points.iter().enumerate() {
            let b = points[(i + 1) % points.len()];
            let (x0, x1) = (a[0].min(b[0]), a[0].max(b[0]));
            let (y0, y1) = (a[1].min(b[1]), a[1].max(b[1]));
            let ys =
                (y0.ceil().max(0.0) as i64)..=(y1.floor().min(self.height as f64 - 1.0) as i64);
            for y in ys {
                let xs =
                    (x0.ceil().max(0.0) as i64)..=(x1.floor().min(self.width as f64 - 1.0) as i64);
                for x in xs {
                    let (px, py) = (x as f64 - a[0], y as f64 - a[1]);
                    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                    if (dx * py - dy * px).abs() <= 1e-9 * (dx.abs() + dy.abs()).max(1.0) {
                        self.data[y as usize * self.width + x as usize] = true;
                    }
                }
            }
        }
        let mut xs: Vec<f64> = Vec::new();
        for y in 0..self.height {
            let yf = y as f64;
            xs.clear();
            for (i, a) in points.iter().enumerate() {
                let b = points[(i + 1) % points.len()];
                let (lo, hi) = if a[1] <= b[1] { (a, &b) } else { (&b, a) };
                // Half-open in y so a vertex shared by two edges is counted once.
                if lo[1] <= yf && yf < hi[1] {
                    xs.push(lo[0] + (yf - lo[1]) * (hi[0] - lo[0]) / (hi[1] - lo[1]));
                }
            }
            xs.sort_by(f64::total_cmp);
            for pair in xs.chunks_exact(2) {
                let x0 = pair[0].ceil().max(0.0);
                let x1 = pair[1].floor().min(self.width as f64 - 1.0);
                if x0 <= x1 {
                    let row = y * self.width;
                    self.data[row + x0 as usize..=row + x1 as usize].fill(true);
                }
            }
        }
    }
}

/// Pixels of an 8-bit face-id image equal to `id`.
pub fn face_mask(faces: &DynamicImage, path: &Path, id: u8) -> Result<Mask, MetricsError> {
    let DynamicImage::ImageLuma8(b) = faces else {
        return Err(MetricsError::field(
            path,
            "faces",
            format!(
                "expected an 8-bit grayscale face-id PNG, found {:?}",
                faces.color()
            ),
        ));
    };
    Ok(Mask {
        width: b.width() as usize,
        height: b.height() as usize,
        data: b.as_raw().iter().map(|&v| v == id).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polygon_fill_uses_integer_pixel_centres() {
        let mut m = Mask::filled(8, 6, false);
        m.fill_polygon(&[[2.0, 1.0], [5.0, 1.0], [5.0, 4.0], [2.0, 4.0]]);
        // x in 2..=5, y in 1..=4: centres inside or on the edges, as PIL's fill plus
        // outline (LabelMe's shape_to_mask).
        let want: Vec<bool> = (0..48)
            .map(|i| (2..=5).contains(&(i % 8)) && (1..=4).contains(&(i / 8)))
            .collect();
        assert_eq!(m.data, want);
        assert_eq!(
            m.bbox(),
            Some(Rect {
                x0: 2,
                y0: 1,
                x1: 6,
                y1: 5
            })
        );
        // A triangle covers about half its bounding box.
        let mut t = Mask::filled(100, 100, false);
        t.fill_polygon(&[[0.0, 0.0], [99.0, 0.0], [0.0, 99.0]]);
        let n = t.count() as f64;
        assert!((n - 5050.0).abs() < 150.0, "{n}");
        assert!(Mask::filled(3, 3, false).bbox().is_none());
    }
}
