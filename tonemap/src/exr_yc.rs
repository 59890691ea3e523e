//! OpenEXR luminance/chroma images: a full-resolution `Y` with the chroma ratios `RY`
//! (`(R - Y) / Y`) and `BY` (`(B - Y) / Y`) sampled every second pixel and line, as OpenEXR's
//! `RgbaOutputFile` writes them (`WRITE_YC`, `WRITE_YCA`). The exr crate refuses sub-sampled
//! channels, so their scan-line blocks are read here (uncompressed, RLE, ZIP and ZIPS) and
//! turned into RGB the way OpenEXR's `RgbaInputFile` does, so a file reads as OpenEXR's own
//! tools show it:
//! 1. chroma is interpolated to every pixel by a 27-tap filter (14 non-zero taps, nearest
//!    sample at the edges), along each chroma line first, then down the columns, each result
//!    held as a half;
//! 2. `R = (RY + 1) Y`, `B = (BY + 1) Y`, `G = (Y - R yr - B yb) / yg` with the luminance
//!    weights of the file's `chromaticities` (Rec. 709 by default); grey where both chroma
//!    ratios are 0;
//! 3. a pixel more saturated than its four diagonal neighbours allow is pulled towards grey
//!    at the same luminance (OpenEXR's `fixSaturation`, which removes the filter's ringing at
//!    sharp colour edges).
//!
//! The tests compare with `RgbaInputFile`'s output for files OpenEXR wrote.

use std::fs::File;
use std::path::Path;

use exr::compression::Compression;
use exr::meta::header::Header;
use half::f16;

use crate::error::{Error, Result};

/// Whether a part holds luminance/chroma: `Y` with `RY` and `BY` sampled 2x2 under one
/// layer prefix ([`yc_channels`]). A file whose `RY` or `BY` is something else (a full
/// resolution output of that name) is read as any other.
pub(crate) fn is_yc(header: &Header) -> bool {
    yc_channels(header).is_some()
}

/// The indices of `Y`, `RY` and `BY` sharing one layer prefix, with the chroma sampled 2x2:
/// the unprefixed ones first, else the first prefix that has all three (OpenEXR's
/// `RgbaInputFile` reads one layer's three).
fn yc_channels(header: &Header) -> Option<[usize; 3]> {
    let list = &header.channels.list;
    let names: Vec<String> = list.iter().map(|c| c.name.to_string()).collect();
    let prefix = |n: &str| n.rsplit_once('.').map_or("", |(p, _)| p).to_owned();
    let mut prefixes: Vec<String> = names.iter().map(|n| prefix(n)).collect();
    prefixes.sort_by_key(|p| !p.is_empty());
    prefixes.dedup();
    prefixes.into_iter().find_map(|p| {
        let find = |s: &str| {
            let want = if p.is_empty() {
                s.to_owned()
            } else {
                format!("{p}.{s}")
            };
            names.iter().position(|n| *n == want)
        };
        let found = [find("Y")?, find("RY")?, find("BY")?];
        let sampling = |i: usize| (list[i].sampling.0, list[i].sampling.1);
        (sampling(found[1]) == (2, 2) && sampling(found[2]) == (2, 2)).then_some(found)
    })
}

/// The interpolation filter's weights for offsets 1, 3, ..., 13 (and -1, ..., -13).
const WEIGHTS: [f32; 7] = [
    0.627_123, -0.186_077, 0.087_929, -0.043_159, 0.019_597, -0.007_540, 0.002_128,
];

/// Rounded to a half and back, as OpenEXR holds each intermediate.
fn h(v: f32) -> f32 {
    f16::from_f32(v).to_f32()
}

/// The filter at an odd position `p` of a line whose sample `i` sits at position `2 i`:
/// `sample(i)` for `i` already clamped to the line; products summed from offset -13 on.
fn filtered(p: i64, n: usize, sample: impl Fn(usize) -> f32) -> f32 {
    let mut acc = 0.0f32;
    for k in (-13i64..=13).step_by(2) {
        let w = WEIGHTS[(k.unsigned_abs() as usize - 1) / 2];
        let i = (p + k).div_euclid(2).clamp(0, n as i64 - 1) as usize;
        acc += sample(i) * w;
    }
    acc
}

/// Luminance weights (the Y row of the RGB to XYZ matrix, normalised) of chromaticities
/// `r, g, b, white` (CIE xy).
fn luminance_weights(c: Option<&exr::meta::attribute::Chromaticities>) -> [f32; 3] {
    let Some(c) = c else {
        // Rec. 709 primaries and D65, as OpenEXR computes them.
        return [0.212_639, 0.715_168_7, 0.072_192_29];
    };
    let xy = |v: exr::math::Vec2<f32>| (f64::from(v.0), f64::from(v.1));
    let prim = [xy(c.red), xy(c.green), xy(c.blue)];
    let (wx, wy) = xy(c.white);
    // Columns: each primary's XYZ at luminance 1; solve for the scales giving white.
    let col = |(x, y): (f64, f64)| [x / y, 1.0, (1.0 - x - y) / y];
    let m = prim.map(col);
    let white = col((wx, wy));
    let det = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
        a[0] * (b[1] * c[2] - b[2] * c[1]) - b[0] * (a[1] * c[2] - a[2] * c[1])
            + c[0] * (a[1] * b[2] - a[2] * b[1])
    };
    let d = det(m[0], m[1], m[2]);
    let s = [
        det(white, m[1], m[2]) / d,
        det(m[0], white, m[2]) / d,
        det(m[0], m[1], white) / d,
    ];
    let sum: f64 = s.iter().sum();
    let w = s.map(|v| (v / sum) as f32);
    if w.iter().all(|v| v.is_finite() && *v > 0.0) {
        w
    } else {
        [0.212_639, 0.715_168_7, 0.072_192_29]
    }
}

/// OpenEXR's RLE: a signed count byte, then `-count` literal bytes or one byte repeated
/// `count + 1` times; exactly `expected` bytes.
fn rle_decode(data: &[u8], expected: usize) -> std::result::Result<Vec<u8>, &'static str> {
    let mut out = Vec::with_capacity(expected);
    let mut i = 0;
    while i < data.len() {
        let n = data[i] as i8;
        i += 1;
        if n < 0 {
            let k = usize::from(n.unsigned_abs());
            let run = data.get(i..i + k).ok_or("RLE data truncated")?;
            if out.len() + k > expected {
                return Err("RLE data longer than its block");
            }
            out.extend_from_slice(run);
            i += k;
        } else {
            let k = n as usize + 1;
            let &b = data.get(i).ok_or("RLE data truncated")?;
            if out.len() + k > expected {
                return Err("RLE data longer than its block");
            }
            out.resize(out.len() + k, b);
            i += 1;
        }
    }
    if out.len() != expected {
        return Err("a block's data does not match its size");
    }
    Ok(out)
}

/// Reads a single-part scan-line luminance/chroma file as RGB (alpha dropped).
#[cfg(unix)]
pub(crate) fn read(
    path: &Path,
    meta: &exr::meta::MetaData,
    limits: &crate::io::Limits,
) -> Result<image::Rgb32FImage> {
    use std::os::unix::fs::FileExt;
    let unsupported = |m: &str| Error::Unsupported {
        format: "OpenEXR",
        message: format!("luminance/chroma (Y, RY, BY) image: {m}"),
        path: path.into(),
    };
    let invalid = |m: &str| Error::invalid("OpenEXR", m.to_owned(), path);
    let [header] = meta.headers.as_slice() else {
        return Err(unsupported("several parts"));
    };
    if header.deep || !matches!(header.blocks, exr::meta::BlockDescription::ScanLines) {
        return Err(unsupported("tiled or deep"));
    }
    let lines_per_block = match header.compression {
        Compression::Uncompressed | Compression::RLE | Compression::ZIP1 | Compression::ZIP16 => {
            header.compression.scan_lines_per_block()
        }
        other => {
            return Err(unsupported(&format!(
                "{other:?} compression (NONE, RLE, ZIP and ZIPS are read)"
            )));
        }
    };
    let (w, hgt) = (header.layer_size.width(), header.layer_size.height());
    let (x0, y0) = (
        i64::from(header.own_attributes.layer_position.x()),
        i64::from(header.own_attributes.layer_position.y()),
    );
    limits.check_decode(w as u64, hgt as u64, 16)?;
    let list = &header.channels.list;
    let Some([yi, ryi, byi]) = yc_channels(header) else {
        return Err(unsupported(
            "it needs Y, RY and BY channels, RY and BY sampled 2x2",
        ));
    };
    if (list[yi].sampling.0, list[yi].sampling.1) != (1, 1) {
        return Err(unsupported("Y must be at full resolution"));
    }
    if w == 0 || hgt == 0 || w % 2 != 0 || hgt % 2 != 0 || x0 % 2 != 0 || y0 % 2 != 0 {
        return Err(invalid(
            "a data window with chroma sampled 2x2 must start on and span even numbers of pixels",
        ));
    }
    // Samples of channel `c` on line `y` (absolute): those at x and y multiples of its
    // sampling (OpenEXR's rule).
    let count_x = |sx: usize| -> usize {
        let sx = sx.max(1) as i64;
        ((x0 + w as i64 - 1).div_euclid(sx) - (x0 - 1).div_euclid(sx)) as usize
    };
    let sizes: Vec<(usize, usize, usize)> = list
        .iter()
        .map(|c| {
            (
                c.sample_type.bytes_per_sample(),
                c.sampling.1.max(1),
                count_x(c.sampling.0),
            )
        })
        .collect();
    let on_line = |c: usize, y: i64| -> usize {
        let (bytes, sy, n) = sizes[c];
        if y.rem_euclid(sy as i64) == 0 {
            bytes * n
        } else {
            0
        }
    };
    let blocks = hgt.div_ceil(lines_per_block);
    if header.chunk_count != blocks {
        return Err(invalid(
            "the offset table does not match the image's blocks",
        ));
    }
    let file = File::open(path).map_err(|e| Error::io("cannot read", path, e))?;
    let len = file
        .metadata()
        .map_err(|e| Error::io("cannot read", path, e))?
        .len();
    let table_at =
        crate::io::exr_header_end(&file, len, false).ok_or_else(|| invalid("unreadable header"))?;
    let mut table = vec![0u8; blocks * 8];
    file.read_exact_at(&mut table, table_at)
        .map_err(|_| invalid("truncated offset table"))?;
    let (cw, ch) = (w / 2, hgt / 2);
    let mut y_plane = vec![0f32; w * hgt];
    let mut ry = vec![0f32; cw * ch];
    let mut by = vec![0f32; cw * ch];
    let max_block = header.max_block_byte_size() as u64;
    for (b, entry) in table.chunks_exact(8).enumerate() {
        let offset = u64::from_le_bytes(entry.try_into().unwrap_or_default());
        let mut head = [0u8; 8];
        file.read_exact_at(&mut head, offset)
            .map_err(|_| invalid("a block lies outside the file"))?;
        let line = i64::from(i32::from_le_bytes([head[0], head[1], head[2], head[3]]));
        let size = u64::from(u32::from_le_bytes([head[4], head[5], head[6], head[7]]));
        let first = y0 + (b * lines_per_block) as i64;
        if line != first {
            return Err(invalid("a block is not where the offset table says"));
        }
        let lines = lines_per_block.min(hgt - b * lines_per_block);
        let expected: usize = (0..lines as i64)
            .map(|l| {
                (0..list.len())
                    .map(|c| on_line(c, first + l))
                    .sum::<usize>()
            })
            .sum();
        if size > max_block || offset + 8 + size > len {
            return Err(invalid("a block's size runs past the file"));
        }
        let mut data = vec![0u8; size as usize];
        file.read_exact_at(&mut data, offset + 8)
            .map_err(|_| invalid("truncated block"))?;
        let bytes = if data.len() == expected {
            // Stored as it is (compressing did not shrink it).
            data
        } else {
            match header.compression {
                Compression::ZIP1 | Compression::ZIP16 => {
                    crate::exr_zip::decompress(&data, expected).map_err(invalid)?
                }
                Compression::RLE => {
                    let d = rle_decode(&data, expected).map_err(invalid)?;
                    let mut out = vec![0u8; expected];
                    crate::exr_zip::undo_predictor(&d, &mut out);
                    out
                }
                _ => return Err(invalid("a block's data does not match its size")),
            }
        };
        // Line by line, the channels in their order in the file.
        let mut at = 0;
        for l in 0..lines {
            let y = first + l as i64;
            let row = (y - y0) as usize;
            for c in 0..list.len() {
                let n = on_line(c, y);
                let samples = &bytes[at..at + n];
                at += n;
                let dest: &mut [f32] = if c == yi {
                    &mut y_plane[row * w..(row + 1) * w]
                } else if c == ryi {
                    &mut ry[row / 2 * cw..(row / 2 + 1) * cw]
                } else if c == byi {
                    &mut by[row / 2 * cw..(row / 2 + 1) * cw]
                } else {
                    continue;
                };
                if n == 0 {
                    continue;
                }
                let t = list[c].sample_type;
                for (o, s) in dest
                    .iter_mut()
                    .zip(samples.chunks_exact(t.bytes_per_sample()))
                {
                    *o = match t {
                        exr::meta::attribute::SampleType::F16 => {
                            f16::from_le_bytes([s[0], s[1]]).to_f32()
                        }
                        exr::meta::attribute::SampleType::F32 => {
                            f32::from_le_bytes([s[0], s[1], s[2], s[3]])
                        }
                        exr::meta::attribute::SampleType::U32 => {
                            u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f32
                        }
                    };
                }
            }
        }
    }
    // RgbaInputFile holds every channel as a half: float samples are rounded as it reads.
    for v in y_plane.iter_mut().chain(ry.iter_mut()).chain(by.iter_mut()) {
        *v = h(*v);
    }
    let yw = luminance_weights(header.shared_attributes.chromaticities.as_ref());
    Ok(to_rgb(&y_plane, &ry, &by, w, hgt, yw))
}

#[cfg(not(unix))]
pub(crate) fn read(
    path: &Path,
    _: &exr::meta::MetaData,
    _: &crate::io::Limits,
) -> Result<image::Rgb32FImage> {
    Err(Error::Unsupported {
        format: "OpenEXR",
        message: "luminance/chroma images are read on Unix only".into(),
        path: path.into(),
    })
}

/// RGB of `w x h` luminance samples `y` and `w/2 x h/2` chroma samples `ry`, `by` with
/// luminance weights `yw`, as `RgbaInputFile` reconstructs them (module docs).
fn to_rgb(
    y: &[f32],
    ry: &[f32],
    by: &[f32],
    w: usize,
    hgt: usize,
    yw: [f32; 3],
) -> image::Rgb32FImage {
    use rayon::prelude::*;
    let (cw, ch) = (w / 2, hgt / 2);
    // 1. Along each chroma line: every pixel of the even image rows.
    let horizontal = |c: &[f32]| -> Vec<f32> {
        let mut out = vec![0f32; ch * w];
        out.par_chunks_mut(w).enumerate().for_each(|(j, o)| {
            let line = &c[j * cw..(j + 1) * cw];
            for (x, v) in o.iter_mut().enumerate() {
                *v = if x % 2 == 0 {
                    line[x / 2]
                } else {
                    h(filtered(x as i64, cw, |i| line[i]))
                };
            }
        });
        out
    };
    let (ryh, byh) = (horizontal(ry), horizontal(by));
    // The chroma of image row `r` (-1 ..= h): the even rows' own, the odd rows' filtered
    // down the columns; rows past the bottom take the last chroma line.
    let chroma = |r: i64, x: usize| -> (f32, f32) {
        if r.rem_euclid(2) == 0 {
            let j = (r / 2).clamp(0, ch as i64 - 1) as usize;
            (ryh[j * w + x], byh[j * w + x])
        } else {
            (
                h(filtered(r, ch, |j| ryh[j * w + x])),
                h(filtered(r, ch, |j| byh[j * w + x])),
            )
        }
    };
    // 2. RGB of row `r` (-1 ..= h): above the image the first row's luminance, below it
    // row h - 2's (OpenEXR's clamping).
    let rgb_row = |r: i64| -> Vec<[f32; 3]> {
        let yr = if r < 0 {
            0
        } else if r > hgt as i64 - 1 {
            hgt - 2
        } else {
            r as usize
        };
        (0..w)
            .map(|x| {
                let (cr, cb) = chroma(r, x);
                let l = y[yr * w + x];
                if cr == 0.0 && cb == 0.0 {
                    return [l; 3];
                }
                let red = (cr + 1.0) * l;
                let blue = (cb + 1.0) * l;
                let green = (l - red * yw[0] - blue * yw[2]) / yw[1];
                [h(red), h(green), h(blue)]
            })
            .collect()
    };
    let rows: Vec<Vec<[f32; 3]>> = (-1..=hgt as i64).into_par_iter().map(rgb_row).collect();
    // 3. The saturation fix against each pixel's four diagonal neighbours.
    let sat = |p: &[f32; 3]| {
        let mx = p[0].max(p[1]).max(p[2]);
        let mn = p[0].min(p[1]).min(p[2]);
        if mx > 0.0 { 1.0 - mn / mx } else { 0.0 }
    };
    let lum = |p: &[f32; 3]| p[0] * yw[0] + p[1] * yw[1] + p[2] * yw[2];
    let mut out = image::Rgb32FImage::new(w as u32, hgt as u32);
    out.par_chunks_mut(3 * w).enumerate().for_each(|(r, o)| {
        let (above, cur, below) = (&rows[r], &rows[r + 1], &rows[r + 2]);
        for x in 0..w {
            let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let mut p = cur[x];
            let s = sat(&p);
            let mean = (0.25
                * (sat(&above[xl]) + sat(&above[xr]) + sat(&below[xl]) + sat(&below[xr])))
            .min(1.0);
            if s > mean {
                let most = (1.0 - (1.0 - mean) * 0.25).min(1.0);
                if s > most {
                    let f = most / s;
                    let m = p[0].max(p[1]).max(p[2]);
                    let q = p.map(|c| h((m - (m - c) * f).max(0.0)));
                    let (yin, yout) = (lum(&p), lum(&q));
                    p = if yout > 0.0 {
                        q.map(|c| h(c * (yin / yout)))
                    } else {
                        q
                    };
                }
            }
            o[3 * x..3 * x + 3].copy_from_slice(&p);
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_runs_and_literals_decode_and_lies_are_refused() {
        // 3 x 7, then the literals 1 2.
        assert_eq!(rle_decode(&[2, 7, 0xfe, 1, 2], 5).unwrap(), [7, 7, 7, 1, 2]);
        assert!(rle_decode(&[2, 7], 4).is_err());
        assert!(rle_decode(&[0xfe, 1], 2).is_err());
        assert!(rle_decode(&[5, 7], 3).is_err());
    }

    #[test]
    fn rec709_weights_are_openexrs() {
        use exr::math::Vec2;
        let c = exr::meta::attribute::Chromaticities {
            red: Vec2(0.64, 0.33),
            green: Vec2(0.30, 0.60),
            blue: Vec2(0.15, 0.06),
            white: Vec2(0.3127, 0.3290),
        };
        let w = luminance_weights(Some(&c));
        let want = luminance_weights(None);
        for i in 0..3 {
            assert!((w[i] - want[i]).abs() < 1e-6, "{w:?} {want:?}");
        }
    }
}
