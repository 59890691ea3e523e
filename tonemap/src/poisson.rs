//! A direct Poisson solver with Neumann boundaries by the discrete cosine transform.
//!
//! The 5-point Laplacian with reflecting (zero-flux) boundaries, in which a neighbour
//! outside the image is replaced by the pixel itself, is diagonalised by the 2-D DCT-II:
//! its eigenvalues are `(2 cos(pi k / W) - 2) + (2 cos(pi l / H) - 2)`. Solving is a forward
//! DCT, a division, and an inverse DCT: O(N log N), exact up to rounding (Fattal et al.
//! 2002 Sec. 5 name this "Poisson equation ... with Neumann boundary conditions").

use rayon::prelude::*;
use rustdct::DctPlanner;

use crate::error::{Error, Result};

/// Applies the Neumann 5-point Laplacian to a row-major `width` x `height` field.
#[must_use]
pub fn laplacian_neumann(u: &[f64], width: usize, height: usize) -> Vec<f64> {
    let mut out = vec![0.0; u.len()];
    if width == 0 {
        return out;
    }
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let c = u[y * width + x];
            let mut s = 0.0;
            if x > 0 {
                s += u[y * width + x - 1] - c;
            }
            if x + 1 < width {
                s += u[y * width + x + 1] - c;
            }
            if y > 0 {
                s += u[(y - 1) * width + x] - c;
            }
            if y + 1 < height {
                s += u[(y + 1) * width + x] - c;
            }
            *o = s;
        }
    });
    out
}

/// Solves `laplacian_neumann(u) = f` for `u` with zero mean.
///
/// `f` must sum to zero (the compatibility condition of the Neumann problem); its mean is
/// removed, which is the least-squares solution otherwise.
///
/// # Errors
/// [`Error::Parameter`] when `f.len() != width * height` or the field is empty.
pub fn solve_poisson_neumann(f: &[f64], width: usize, height: usize) -> Result<Vec<f64>> {
    if width == 0 || height == 0 || f.len() != width * height {
        return Err(Error::parameter(format!(
            "Poisson solver: field of {} values for {width} x {height}",
            f.len()
        )));
    }
    let mut planner = DctPlanner::<f64>::new();
    let (row2, row3) = (planner.plan_dct2(width), planner.plan_dct3(width));
    let (col2, col3) = (planner.plan_dct2(height), planner.plan_dct3(height));

    let mut a = f.to_vec();
    dct_rows(&mut a, width, row2.get_scratch_len(), None, |r, s| {
        row2.process_dct2_with_scratch(r, s)
    });
    let mut t = transpose(&a, width, height);
    dct_rows(&mut t, height, col2.get_scratch_len(), None, |r, s| {
        col2.process_dct2_with_scratch(r, s)
    });
    // t is [x][y]: divide by the eigenvalues.
    let cx: Vec<f64> = (0..width)
        .map(|k| 2.0 * (std::f64::consts::PI * k as f64 / width as f64).cos() - 2.0)
        .collect();
    let cy: Vec<f64> = (0..height)
        .map(|l| 2.0 * (std::f64::consts::PI * l as f64 / height as f64).cos() - 2.0)
        .collect();
    t.par_chunks_mut(height).enumerate().for_each(|(k, col)| {
        for (l, v) in col.iter_mut().enumerate() {
            let lambda = cx[k] + cy[l];
            *v = if k == 0 && l == 0 { 0.0 } else { *v / lambda };
        }
    });
    dct_rows(
        &mut t,
        height,
        col3.get_scratch_len(),
        Some(2.0 / height as f64),
        |r, s| col3.process_dct3_with_scratch(r, s),
    );
    let mut u = transpose(&t, height, width);
    dct_rows(
        &mut u,
        width,
        row3.get_scratch_len(),
        Some(2.0 / width as f64),
        |r, s| row3.process_dct3_with_scratch(r, s),
    );
    Ok(u)
}

fn dct_rows(
    data: &mut [f64],
    len: usize,
    scratch_len: usize,
    scale: Option<f64>,
    run: impl Fn(&mut [f64], &mut [f64]) + Sync,
) {
    data.par_chunks_mut(len).for_each_init(
        || vec![0.0; scratch_len],
        |scratch, row| {
            run(row, scratch);
            if let Some(s) = scale {
                row.iter_mut().for_each(|v| *v *= s);
            }
        },
    );
}

/// Transposes a row-major `width` x `height` array into `height` x `width`.
fn transpose(a: &[f64], width: usize, height: usize) -> Vec<f64> {
    let mut out = vec![0.0; a.len()];
    out.par_chunks_mut(height).enumerate().for_each(|(x, col)| {
        for (y, v) in col.iter_mut().enumerate() {
            *v = a[y * width + x];
        }
    });
    out
}
