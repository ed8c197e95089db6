//! 2D complex FFT (rows, transpose, rows, transpose), parallel over rows. Unnormalised
//! like rustfft: forward then inverse multiplies by w * h.

use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex32;

pub(crate) fn fft2(data: &mut [Complex32], w: usize, h: usize, inverse: bool) {
    let mut planner = FftPlanner::<f32>::new();
    rows(&mut planner, data, w, inverse);
    let mut t = transpose(data, w, h);
    rows(&mut planner, &mut t, h, inverse);
    let back = transpose(&t, h, w);
    data.copy_from_slice(&back);
}

fn rows(planner: &mut FftPlanner<f32>, data: &mut [Complex32], n: usize, inverse: bool) {
    let plan = if inverse {
        planner.plan_fft_inverse(n)
    } else {
        planner.plan_fft_forward(n)
    };
    let scratch_len = plan.get_inplace_scratch_len();
    data.par_chunks_mut(n).for_each_init(
        || vec![Complex32::new(0.0, 0.0); scratch_len],
        |scratch, row| plan.process_with_scratch(row, scratch),
    );
}

/// `src` is `w` wide and `h` tall; the result is `h` wide and `w` tall.
fn transpose(src: &[Complex32], w: usize, h: usize) -> Vec<Complex32> {
    let mut out = vec![Complex32::new(0.0, 0.0); w * h];
    const B: usize = 32;
    out.par_chunks_mut(h * B)
        .enumerate()
        .for_each(|(bx, chunk)| {
            let x0 = bx * B;
            let xs = chunk.len() / h;
            for y0 in (0..h).step_by(B) {
                for y in y0..(y0 + B).min(h) {
                    for dx in 0..xs {
                        chunk[dx * h + y] = src[y * w + x0 + dx];
                    }
                }
            }
        });
    out
}
