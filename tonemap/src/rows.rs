//! Global tone mapping over the rows of an [`HdrSource`], without its floating-point image:
//! a first pass for the statistics the curve needs, a second from the rows again to the
//! display codes. Each row goes through the same steps as the whole-image path
//! ([`crate::CleanImage::from_image`], [`crate::plane::log_average`],
//! [`crate::plane::recolour_with_srgb8`]), so the codes are the same bytes.

use std::borrow::Cow;
use std::path::Path;

use rayon::prelude::*;

use crate::error::Result;
use crate::io::{HdrSource, RowScratch};
use crate::plane::{log_average_of_rows, log_sum_row, recolour_row_of};
use crate::sanitize::{
    CleanStats, SanitizeReport, clean_row, luminance_into, luminance_row_stats,
    merge_luminance_rows, merge_rows,
};

/// One thread's buffers for one row.
pub(crate) struct RowBuffers {
    scratch: RowScratch,
    rgb: Vec<f32>,
    lum: Vec<f32>,
    /// Logarithms (first pass) or output luminances (second pass).
    work: Vec<f32>,
    /// Whether the dirty-input rule may change a value (not after a first pass that found
    /// nothing to change; nor in rows the source knows to be clean,
    /// [`HdrSource::row_is_clean`]).
    rule: bool,
}

impl RowBuffers {
    fn new(src: &HdrSource, rule: bool) -> Self {
        let w = src.dimensions().0 as usize;
        Self {
            scratch: RowScratch::default(),
            rgb: vec![0.0; 3 * w],
            lum: vec![0.0; w],
            work: vec![0.0; w],
            rule,
        }
    }

    /// Row `y`'s luminance only, where the source gives it without its values (a compact
    /// source, whose values need no cleaning), else as [`RowBuffers::clean`].
    fn luminance(
        &mut self,
        src: &HdrSource,
        y: usize,
    ) -> ((SanitizeReport, [f32; 3]), (f32, f32, u64)) {
        if src.luminance_row(y, &mut self.scratch, &mut self.lum) {
            let clean = (SanitizeReport::default(), [0.0; 3]);
            return (clean, luminance_row_stats(&self.lum));
        }
        self.clean(src, y)
    }

    /// Row `y` of `src`, cleaned, with its luminance: the row's report, largest finite
    /// value per channel and luminance statistics.
    fn clean(
        &mut self,
        src: &HdrSource,
        y: usize,
    ) -> ((SanitizeReport, [f32; 3]), (f32, f32, u64)) {
        let cleaned = self.load(src, y);
        (cleaned, luminance_stats(&self.rgb, &mut self.lum))
    }

    /// Row `y` of `src`, cleaned (the second pass, whose codes may not need the
    /// luminance): the row's report and largest finite value per channel.
    fn load(&mut self, src: &HdrSource, y: usize) -> (SanitizeReport, [f32; 3]) {
        src.decode_row(y, &mut self.scratch, &mut self.rgb);
        clean_unless(&mut self.rgb, !self.rule || src.row_is_clean(y))
    }
}

/// A decoded RGB row under the dirty-input rule, unless `clean` (nothing to change): the
/// row's report and largest finite value per channel.
fn clean_unless(rgb: &mut [f32], clean: bool) -> (SanitizeReport, [f32; 3]) {
    if clean {
        (SanitizeReport::default(), [0.0; 3])
    } else {
        clean_row(rgb)
    }
}

/// A cleaned RGB row's luminance into `lum`, and its statistics.
fn luminance_stats(rgb: &[f32], lum: &mut [f32]) -> (f32, f32, u64) {
    luminance_into(rgb, lum);
    luminance_row_stats(lum)
}

/// One row's statistics of the first pass: the cleaning's report and largest finite value
/// per channel, the luminance's smallest positive value, largest value and zero count, and
/// the sum of the logarithms of the positive luminances with their count (over the whole
/// row).
pub(crate) type RowStats = ((SanitizeReport, [f32; 3]), (f32, f32, u64), (f64, u64));

/// One thread's buffers for the first pass's statistics of the rows of a band as it is
/// decoded ([`BandStats::rows`]).
#[derive(Default)]
pub(crate) struct BandStats {
    planes: [Vec<f32>; 3],
    rgb: Vec<f32>,
    lum: Vec<f32>,
    logs: Vec<f32>,
}

impl BandStats {
    /// The statistics of rows `first..first + lines` of an image `w` pixels wide, row `y`
    /// of the band (from 0) written as RGB by `line(y, planes, row)`; `clean`: whether the
    /// band's values are known to be clean. The steps and values of [`clean_stats`]'s pass
    /// (without a circle), so that it can take these instead.
    pub(crate) fn rows(
        &mut self,
        w: usize,
        first: usize,
        lines: usize,
        clean: bool,
        line: impl Fn(usize, &mut [Vec<f32>; 3], &mut [f32]),
    ) -> Vec<RowStats> {
        self.rgb.resize(3 * w, 0.0);
        self.lum.resize(w, 0.0);
        self.logs.resize(w, 0.0);
        (0..lines)
            .map(|y| {
                line(y, &mut self.planes, &mut self.rgb);
                let cleaned = clean_unless(&mut self.rgb, clean);
                let lum = luminance_stats(&self.rgb, &mut self.lum);
                (
                    cleaned,
                    lum,
                    log_sum_row(&self.lum, first + y, None, &mut self.logs),
                )
            })
            .collect()
    }
}

/// The first pass: the cleaning's statistics and, if `log_average`, the log-average
/// luminance over `circle`. `None` when the image has infinite values (their replacement
/// changes the luminances this pass saw).
pub(crate) fn clean_stats(
    src: &HdrSource,
    circle: Option<(f32, f32, f32)>,
    log_average: bool,
) -> Option<(CleanStats, Option<f64>)> {
    let h = src.dimensions().1 as usize;
    // Computed as the source was decoded (the same steps), where the log-average is over the
    // whole image.
    let rows: Cow<[RowStats]> = match src.row_stats().filter(|r| circle.is_none() && r.len() == h) {
        Some(pre) => Cow::Borrowed(pre),
        None => Cow::Owned(
            (0..h)
                .into_par_iter()
                .map_init(
                    || RowBuffers::new(src, true),
                    |b, y| {
                        let (cleaned, lum) = b.luminance(src, y);
                        let logs = if log_average {
                            log_sum_row(&b.lum, y, circle, &mut b.work)
                        } else {
                            (0.0, 0)
                        };
                        (cleaned, lum, logs)
                    },
                )
                .collect(),
        ),
    };
    let cleaned: Vec<_> = rows.iter().map(|r| r.0).collect();
    let (report, _) = merge_rows(&cleaned);
    if report.positive_infinite > 0 {
        return None;
    }
    let (positive_range, zero_pixels) = merge_luminance_rows(rows.iter().map(|r| r.1));
    let lavg = if log_average {
        let logs: Vec<_> = rows.iter().map(|r| r.2).collect();
        log_average_of_rows(&logs)
    } else {
        None
    };
    let stats = CleanStats {
        report,
        positive_range,
        zero_pixels,
    };
    Some((stats, lavg))
}

/// How the second pass makes a row's display codes from the thread's buffers (the row
/// cleaned), the row's index and a display row buffer.
pub(crate) type RowCodes = Box<dyn Fn(&mut RowBuffers, usize, &mut [f32], &mut [u8]) + Sync>;

/// The second pass of a luminance curve ([`crate::plane::recolour_with_srgb8`] row by row).
/// `curve(first pixel, input luminances, output luminances)` gives a row's output luminances.
pub(crate) fn recolour_codes(
    saturation: f32,
    curve: impl Fn(usize, &[f32], &mut [f32]) + Sync + 'static,
) -> RowCodes {
    Box::new(move |b, y, orow, codes| {
        luminance_into(&b.rgb, &mut b.lum);
        let w = b.lum.len();
        recolour_row_of(&b.rgb, &b.lum, y * w, saturation, &curve, &mut b.work, orow);
        crate::io::srgb8_row(orow, codes);
    })
}

/// The second pass of the linear operator (each channel times `scale`).
pub(crate) fn scale_codes(scale: f32) -> RowCodes {
    Box::new(move |b, _, orow, codes| {
        for (o, v) in orow.iter_mut().zip(&b.rgb) {
            *o = v * scale;
        }
        crate::io::srgb8_row(orow, codes);
    })
}

/// Every row of `src` cleaned into a thread's buffers, then its codes, rows in parallel;
/// `rule`: whether the first pass found values the dirty-input rule changes.
pub(crate) fn codes(src: &HdrSource, codes_of: &RowCodes, rule: bool) -> Vec<u8> {
    let (w, h) = src.dimensions();
    let w = w as usize;
    let mut out = vec![0u8; 3 * w * h as usize];
    out.par_chunks_mut(3 * w).enumerate().for_each_init(
        || (RowBuffers::new(src, rule), vec![0.0f32; 3 * w]),
        |(b, orow), (y, codes)| {
            b.load(src, y);
            codes_of(b, y, orow, codes);
        },
    );
    out
}

/// The codes of rows of a source as a PNG compressor asks for them.
struct PngCodeRows<'a> {
    src: &'a HdrSource,
    codes_of: &'a RowCodes,
    rule: bool,
}

impl crate::zlib::PngRows for PngCodeRows<'_> {
    type State = (RowBuffers, Vec<f32>, Vec<u8>);
    fn state(&self) -> Self::State {
        let w = self.src.dimensions().0 as usize;
        (
            RowBuffers::new(self.src, self.rule),
            vec![0.0; 3 * w],
            Vec::new(),
        )
    }
    fn rows<'s>(&'s self, state: &'s mut Self::State, from: usize, to: usize) -> &'s [u8] {
        let (b, orow, codes) = state;
        let n = orow.len();
        codes.resize((to - from) * n, 0);
        for (y, row) in (from..to).zip(codes.chunks_exact_mut(n)) {
            b.load(self.src, y);
            (self.codes_of)(b, y, orow, row);
        }
        codes
    }
}

/// The codes of every row of `src` written as an 8-bit PNG, each part of the file's stream
/// compressed by the thread that made its rows.
pub(crate) fn write_png(
    src: &HdrSource,
    codes_of: &RowCodes,
    rule: bool,
    path: &Path,
) -> Result<()> {
    let (w, h) = src.dimensions();
    let rows = PngCodeRows {
        src,
        codes_of,
        rule,
    };
    crate::io::write_rgb8_png_rows(path, w, h, &rows)
}
