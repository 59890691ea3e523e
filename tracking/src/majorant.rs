//! Majorant grids: for each macrocell, the largest extinction a channel can have there,
//! `max_opacity(tf, [min, max]) * density_scale` (MDWT section 4.3). Data (the macrocell
//! value ranges, from `blueshift-volume`) meets look (the transfer function) here.

use blueshift_tfedit::TransferFunction;
use blueshift_volume::Macrocells;
use rayon::prelude::*;

use crate::dda::CellLayout;

/// Per-macrocell majorant extinction of one channel, per unit world length.
#[derive(Clone, Debug, PartialEq)]
pub struct MajorantGrid {
    layout: CellLayout,
    values: Vec<f32>,
}

/// Widens a value range by a few ulps of its magnitude, so that trilinear interpolation's
/// rounding (which can leave `[min, max]` by a few ulps) stays inside.
fn widen(lo: f32, hi: f32) -> (f64, f64) {
    let m = lo.abs().max(hi.abs());
    let eps = f64::from(m) * 1e-6 + 1e-30;
    (f64::from(lo) - eps, f64::from(hi) + eps)
}

impl MajorantGrid {
    /// Builds the majorant grid of a channel in parallel over cells: for each macrocell the
    /// transfer function's exact maximum opacity over the cell's (slightly widened) value
    /// range, times `density_scale`. A cell whose voxels are all NaN gets the global maximum.
    #[must_use]
    pub fn build(macrocells: &Macrocells, tf: &TransferFunction, density_scale: f32) -> Self {
        let mins = macrocells.mins();
        let maxs = macrocells.maxs();
        let values = mins
            .par_iter()
            .zip(maxs.par_iter())
            .map(|(&lo, &hi)| {
                let op = if lo > hi {
                    tf.global_max_opacity()
                } else {
                    let (a, b) = widen(lo, hi);
                    tf.max_opacity(a..=b)
                };
                op * density_scale
            })
            .collect();
        MajorantGrid {
            layout: CellLayout::of(macrocells),
            values,
        }
    }

    /// A grid whose majorant in each cell is `combine` of the given grids' (same layout).
    /// Used for the sum of N channels' majorants (shadow rays, density blending).
    #[must_use]
    pub fn combined(grids: &[&MajorantGrid], combine: impl Fn(f32, f32) -> f32 + Sync) -> Self {
        let layout = grids[0].layout;
        let values = (0..layout.len())
            .into_par_iter()
            .map(|i| grids.iter().map(|g| g.values[i]).fold(0.0, &combine))
            .collect();
        MajorantGrid { layout, values }
    }

    /// The same grid with rays clipped to the finest level's box ([`CellLayout::framed`]).
    #[must_use]
    pub(crate) fn framed(mut self, finest: &blueshift_volume::Geometry) -> Self {
        self.layout = self.layout.framed(finest);
        self
    }

    /// The cell layout.
    #[must_use]
    pub fn layout(&self) -> &CellLayout {
        &self.layout
    }

    /// The majorants, one per cell, x fastest.
    #[must_use]
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Bytes held by the majorant values.
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        self.values.len() * std::mem::size_of::<f32>()
    }
}
