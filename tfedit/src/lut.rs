//! High-resolution lookup tables (HDR VolVis section 5: 2^16 entries for 16-bit data) and
//! their 2D encoding with duplicated neighbours (HDR VolVis section 6.2, Fig. 8).

use crate::tf::TransferFunction;
use crate::{Error, Result};

/// The shortest table [`TransferFunction::lut`] builds.
pub const MIN_LUT_ENTRIES: usize = 2;
/// The longest table [`TransferFunction::lut`] builds: 2^24 entries (256 MiB of RGBA f32).
pub const MAX_LUT_ENTRIES: usize = 1 << 24;

/// A 1D RGBA lookup table: entry `i` holds `eval(min + i (max - min) / (N - 1))`.
#[derive(Clone, Debug, PartialEq)]
pub struct Lut {
    domain: [f64; 2],
    rgba: Vec<f32>,
}

const CHUNK: usize = 4096;

impl TransferFunction {
    /// Builds a lookup table of `entries` RGBA entries (2 to 2^24; 256 for 8-bit data, 65,536
    /// for 16-bit data). Entry `i` is the transfer function at data value
    /// `min + i (max - min) / (N - 1)`, opacity times alpha_g. The table is the same with or
    /// without the `rayon` feature and on any number of threads.
    pub fn lut(&self, entries: usize) -> Result<Lut> {
        if !(MIN_LUT_ENTRIES..=MAX_LUT_ENTRIES).contains(&entries) {
            return Err(Error::parameter(format!(
                "a lookup table needs {MIN_LUT_ENTRIES} to {MAX_LUT_ENTRIES} entries, got {entries}"
            )));
        }
        let [lo, hi] = self.domain();
        let step = (hi - lo) / (entries - 1) as f64;
        let mut rgba = vec![0f32; entries * 4];
        let fill = |(c, chunk): (usize, &mut [f32])| {
            for (j, px) in chunk.chunks_exact_mut(4).enumerate() {
                let i = c * CHUNK + j;
                let v = if i + 1 == entries { hi } else { lo + i as f64 * step };
                px.copy_from_slice(&self.eval(v));
            }
        };
        #[cfg(feature = "rayon")]
        {
            use rayon::prelude::*;
            rgba.par_chunks_mut(CHUNK * 4).enumerate().for_each(fill);
        }
        #[cfg(not(feature = "rayon"))]
        rgba.chunks_mut(CHUNK * 4).enumerate().for_each(fill);
        Ok(Lut {
            domain: [lo, hi],
            rgba,
        })
    }
}

impl Lut {
    /// Number of entries N.
    #[must_use]
    pub fn len(&self) -> usize {
        self.rgba.len() / 4
    }
    /// Always false: a table has at least two entries.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.rgba.is_empty()
    }
    /// The data domain the table spans, in data units.
    #[must_use]
    pub fn domain(&self) -> [f64; 2] {
        self.domain
    }
    /// Entry `i` as RGBA, or `None` past the end.
    #[must_use]
    pub fn get(&self, i: usize) -> Option<[f32; 4]> {
        let p = self.rgba.get(i * 4..i * 4 + 4)?;
        Some([p[0], p[1], p[2], p[3]])
    }
    /// All entries as interleaved RGBA f32 (N x 4 numbers), ready for an image or a texture.
    #[must_use]
    pub fn as_rgba(&self) -> &[f32] {
        &self.rgba
    }
    /// Consumes the table, giving the interleaved RGBA numbers.
    #[must_use]
    pub fn into_rgba(self) -> Vec<f32> {
        self.rgba
    }

    /// Fractional entry index of a data value, clamped to `[0, N - 1]` (the texture
    /// coordinate of a 1D lookup in entry units).
    #[must_use]
    pub fn position(&self, value: f64) -> f64 {
        let [lo, hi] = self.domain;
        let n = (self.len() - 1) as f64;
        ((value - lo) / (hi - lo) * n).clamp(0.0, n)
    }

    /// Linear interpolation of the table at fractional entry index `p` (what a GPU's 1D
    /// linear filter does), clamped at both ends.
    #[must_use]
    pub fn sample_position(&self, p: f64) -> [f32; 4] {
        let n = self.len();
        let p = p.clamp(0.0, (n - 1) as f64);
        let i = (p.floor() as usize).min(n - 2);
        let f = (p - i as f64) as f32;
        let a = &self.rgba[i * 4..i * 4 + 4];
        let b = &self.rgba[i * 4 + 4..i * 4 + 8];
        std::array::from_fn(|c| lerp(a[c], b[c], f))
    }
}

#[inline]
pub(crate) fn lerp(a: f32, b: f32, f: f32) -> f32 {
    a + (b - a) * f
}

/// A long 1D table stored as `m` rows of `n + 2` texels (HDR VolVis Fig. 8).
///
/// Row `k` holds entries `k n .. k n + n - 1` in texels `1 ..= n`; texel 0 duplicates entry
/// `k n - 1` (the last entry of the previous row) and texel `n + 1` duplicates entry
/// `(k + 1) n` (the first entry of the next row), clamped at the ends of the table. A linear
/// filter inside one row then reproduces the 1D table's linear interpolation across every
/// row break. A last row that is only partly filled repeats the last entry.
#[derive(Clone, Debug, PartialEq)]
pub struct Lut2d {
    entries: usize,
    n: usize,
    rows: usize,
    rgba: Vec<f32>,
}

impl Lut2d {
    /// Encodes `lut` into rows of `n` entries each (texture width `n + 2`).
    pub fn encode(lut: &Lut, n: usize) -> Result<Self> {
        let len = lut.len();
        if n == 0 || n > len {
            return Err(Error::parameter(format!(
                "2D encoding: row length {n} must be between 1 and the table length {len}"
            )));
        }
        let rows = len.div_ceil(n);
        let width = n + 2;
        let mut rgba = Vec::with_capacity(rows * width * 4);
        for k in 0..rows {
            for col in 0..width {
                let i = (k * n + col).saturating_sub(1).min(len - 1);
                rgba.extend_from_slice(&lut.rgba[i * 4..i * 4 + 4]);
            }
        }
        Ok(Self {
            entries: len,
            n,
            rows,
            rgba,
        })
    }

    /// Encodes `lut` for textures no wider or taller than `max_dim` texels (4,096 in the
    /// paper): rows of `max_dim - 2` entries, at most `max_dim` rows (16,769,024 entries for
    /// 4,096).
    pub fn encode_for_max_texture(lut: &Lut, max_dim: usize) -> Result<Self> {
        if max_dim < 3 {
            return Err(Error::parameter(format!(
                "2D encoding: the texture size limit {max_dim} must be at least 3"
            )));
        }
        let n = (max_dim - 2).min(lut.len());
        let rows = lut.len().div_ceil(n);
        if rows > max_dim {
            return Err(Error::parameter(format!(
                "2D encoding: {} entries need {rows} rows of {n}, more than the limit {max_dim}",
                lut.len()
            )));
        }
        Self::encode(lut, n)
    }

    /// Entries per row, n.
    #[must_use]
    pub fn row_len(&self) -> usize {
        self.n
    }
    /// Texture width n + 2.
    #[must_use]
    pub fn width(&self) -> usize {
        self.n + 2
    }
    /// Number of rows m.
    #[must_use]
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Number of 1D entries encoded.
    #[must_use]
    pub fn entries(&self) -> usize {
        self.entries
    }
    /// Texels row by row, interleaved RGBA (m x (n + 2) x 4 numbers).
    #[must_use]
    pub fn as_rgba(&self) -> &[f32] {
        &self.rgba
    }
    /// Texel `(row, col)` as RGBA.
    #[must_use]
    pub fn texel(&self, row: usize, col: usize) -> Option<[f32; 4]> {
        if row >= self.rows || col >= self.width() {
            return None;
        }
        let o = (row * self.width() + col) * 4;
        Some([self.rgba[o], self.rgba[o + 1], self.rgba[o + 2], self.rgba[o + 3]])
    }

    /// Where 1D entry `i` lives: `(row, col)` with `col` in `1 ..= n`.
    #[must_use]
    pub fn texel_of_entry(&self, i: usize) -> Option<(usize, usize)> {
        (i < self.entries).then(|| (i / self.n, i % self.n + 1))
    }

    /// Which 1D entry texel `(row, col)` holds (border texels hold a neighbour row's
    /// entry, clamped at the table's ends); `None` outside the texture.
    #[must_use]
    pub fn entry_of_texel(&self, row: usize, col: usize) -> Option<usize> {
        if row >= self.rows || col >= self.width() {
            return None;
        }
        Some((row * self.n + col).saturating_sub(1).min(self.entries - 1))
    }

    /// Maps a fractional 1D entry index `p` (in `[0, N - 1]`, clamped) to the texel-space
    /// column `x` (texel centres at integers, in `[0, n + 1]`) and the row: entries
    /// `k n - 1 <= p < (k + 1) n - 1` go to row `k`, so a lookup never leaves its row.
    /// The normalised texture coordinates are `((x + 0.5) / (n + 2), (row + 0.5) / m)`.
    #[must_use]
    pub fn coords_of_position(&self, p: f64) -> (f64, usize) {
        let p = p.clamp(0.0, (self.entries - 1) as f64);
        let n = self.n as f64;
        let row = (((p + 1.0) / n).floor() as usize).min(self.rows - 1);
        (p - row as f64 * n + 1.0, row)
    }

    /// Inverse of [`Lut2d::coords_of_position`]: the fractional 1D index at texel-space
    /// column `x` of `row`.
    #[must_use]
    pub fn position_of_coords(&self, x: f64, row: usize) -> f64 {
        row as f64 * self.n as f64 + x - 1.0
    }

    /// A GPU-style linear lookup in one row at texel-space column `x` (the row is sampled at
    /// its centre, so no blending between rows).
    #[must_use]
    pub fn sample_row(&self, x: f64, row: usize) -> [f32; 4] {
        let w = self.width();
        let row = row.min(self.rows - 1);
        let x = x.clamp(0.0, (w - 1) as f64);
        let c = (x.floor() as usize).min(w - 2);
        let f = (x - c as f64) as f32;
        let o = (row * w + c) * 4;
        let a = &self.rgba[o..o + 4];
        let b = &self.rgba[o + 4..o + 8];
        std::array::from_fn(|k| lerp(a[k], b[k], f))
    }

    /// Looks up fractional 1D index `p` through the 2D texture.
    #[must_use]
    pub fn sample_position(&self, p: f64) -> [f32; 4] {
        let (x, row) = self.coords_of_position(p);
        self.sample_row(x, row)
    }
}
