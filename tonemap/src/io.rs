//! HDR image input and output: OpenEXR (through `exr`), Radiance `.hdr` (run-length
//! scanlines decoded here in parallel, anything else through `image`), PFM, 8- and 16-bit
//! PNG (compressed by [`crate::zlib`]), and numbered EXR sequences for HDR video.
//!
//! Readers check the image size against [`Limits`] before allocating pixels and turn
//! truncated or malformed files into [`Error::Invalid`]. Writers write to a temporary
//! file in the destination folder and rename it, so a failure never leaves half a file.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use image::{ImageDecoder, Rgb32FImage, RgbImage};

use crate::error::{Error, Result};

/// Size limits checked before any pixel buffer is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted width x height (default 2^27 = 134 M pixels, 1.6 GB as RGB f32).
    pub max_pixels: u64,
    /// Largest number of bytes a reader may allocate while decoding (default: no cap beyond
    /// `max_pixels`; the CLI sets its memory budget here). A reader estimates its peak
    /// (the decoded samples, [`DECODE_BYTES_PER_PIXEL`] for the RGB f32 result and its
    /// copy) from the header, before decoding.
    pub max_bytes: u64,
}

/// Bytes per pixel every reader holds at its peak besides the file's own samples: the
/// RGB f32 image and one RGB f32 copy while it is assembled.
pub const DECODE_BYTES_PER_PIXEL: u64 = 24;

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_pixels: 1 << 27,
            max_bytes: u64::MAX,
        }
    }
}

impl Limits {
    fn check(&self, width: u64, height: u64) -> Result<()> {
        self.check_decode(width, height, 0)
    }

    /// Checks the pixel count, then the bytes of decoding `width` x `height` pixels with
    /// `sample_bytes` per pixel of decoded file samples on top of
    /// [`DECODE_BYTES_PER_PIXEL`].
    pub(crate) fn check_decode(&self, width: u64, height: u64, sample_bytes: u64) -> Result<()> {
        let pixels = match width.checked_mul(height) {
            Some(n) if n <= self.max_pixels => n,
            _ => {
                return Err(Error::Limits {
                    width,
                    height,
                    max_pixels: self.max_pixels,
                });
            }
        };
        let needed = pixels.saturating_mul(DECODE_BYTES_PER_PIXEL.saturating_add(sample_bytes));
        if needed > self.max_bytes {
            return Err(Error::Memory {
                width,
                height,
                needed,
                max_bytes: self.max_bytes,
            });
        }
        Ok(())
    }
}

/// The HDR file formats this module reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HdrFormat {
    /// OpenEXR.
    Exr,
    /// Radiance RGBE (`.hdr`, `.pic`).
    Radiance,
    /// Portable float map.
    Pfm,
}

/// Detects the format from the first bytes of the file (not the extension).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::Unsupported`] for an unknown format.
pub fn detect_format(path: &Path) -> Result<HdrFormat> {
    // A FIFO or device would block or never end: only regular files are read.
    let meta = std::fs::metadata(path).map_err(|e| Error::io("cannot read", path, e))?;
    if !meta.is_file() {
        return Err(Error::invalid(
            "HDR image",
            "not a regular file (a FIFO, device, socket or folder)",
            path,
        ));
    }
    let mut head = Vec::with_capacity(2048);
    File::open(path)
        .and_then(|f| f.take(2048).read_to_end(&mut head))
        .map_err(|e| Error::io("cannot read", path, e))?;
    if head.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        return Ok(HdrFormat::Exr);
    }
    if head.len() >= 3
        && (head.starts_with(b"PF") || head.starts_with(b"Pf"))
        && head[2].is_ascii_whitespace()
    {
        return Ok(HdrFormat::Pfm);
    }
    if find(&head, b"#?RADIANCE").is_some() || find(&head, b"#?RGBE").is_some() {
        return Ok(HdrFormat::Radiance);
    }
    Err(Error::Unsupported {
        format: "HDR image",
        message: "not OpenEXR, Radiance HDR or PFM (unknown magic bytes)".into(),
        path: path.into(),
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Reads an HDR image (`.exr`, `.hdr` or `.pfm`, detected from its content) with the
/// default [`Limits`]. Alpha is dropped; a luminance-only file becomes grey RGB.
///
/// # Errors
/// See [`read_hdr_image_with`].
pub fn read_hdr_image(path: impl AsRef<Path>) -> Result<Rgb32FImage> {
    read_hdr_image_with(path, &Limits::default())
}

/// Reads an HDR image with explicit limits.
///
/// # Errors
/// [`Error::Io`] (missing file, permissions), [`Error::Invalid`] (malformed or truncated),
/// [`Error::Unsupported`], [`Error::Limits`] (too large).
pub fn read_hdr_image_with(path: impl AsRef<Path>, limits: &Limits) -> Result<Rgb32FImage> {
    let path = path.as_ref();
    match detect_format(path)? {
        HdrFormat::Exr => read_exr(path, limits),
        HdrFormat::Radiance => read_radiance(path, limits),
        HdrFormat::Pfm => read_pfm(path, limits),
    }
}

fn exr_error(e: exr::error::Error, path: &Path) -> Error {
    use exr::error::Error as E;
    match e {
        E::NotSupported(m) => Error::Unsupported {
            format: "OpenEXR",
            message: m.into_owned(),
            path: path.into(),
        },
        E::Invalid(m) => Error::invalid("OpenEXR", m.into_owned(), path),
        E::Aborted => Error::invalid("OpenEXR", "reading aborted", path),
        E::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::invalid("OpenEXR", "truncated file", path)
        }
        E::Io(io) => Error::io("cannot read", path, io),
    }
}

/// Reads the first part of an OpenEXR file with R, G, B (A ignored) or Y alone, in half,
/// float or uint samples. Channel names may carry a layer prefix (`diffuse.R`).
///
/// # Errors
/// As [`read_hdr_image_with`]; [`Error::Unsupported`] for deep data or files without
/// R, G, B or Y channels.
pub fn read_exr(path: &Path, limits: &Limits) -> Result<Rgb32FImage> {
    Ok(read_exr_source(path, limits, false)?.into_image())
}

/// [`read_exr`] as an [`HdrSource`]: a single-part flat image with R, G, B (or Y) channels
/// keeps its blocks' decompressed samples (half floats stay half: half the memory of the
/// `f32` image), every other file is decoded by the exr crate's image reader.
///
/// With `compact` false, the block reader converts each band into the image as soon as it is
/// decompressed (the image readers: no blocks held).
fn read_exr_source(path: &Path, limits: &Limits, compact: bool) -> Result<HdrSource> {
    use exr::prelude::{FlatSamples, ReadChannels, ReadLayers, read};
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(e, path))?;
    let file_len = std::fs::metadata(path)
        .map_err(|e| Error::io("cannot read", path, e))?
        .len();
    for header in meta.headers.iter() {
        let size = header.layer_size;
        // Every channel is decoded as f32 (at most) before R, G, B are picked.
        let samples = 4 * header.channels.list.len() as u64;
        limits.check_decode(size.width() as u64, size.height() as u64, samples)?;
        exr_fits_in_file(header, file_len, path)?;
    }
    // Luminance/chroma (`Y`, `RY`, `BY`): the exr crate reads no sub-sampled channels.
    if let [header] = meta.headers.as_slice()
        && crate::exr_yc::is_yc(header)
    {
        return Ok(HdrSource::from_image(crate::exr_yc::read(
            path, &meta, limits,
        )?));
    }
    match read_exr_blocks(path, compact)? {
        Some(ExrRead::Bands(bands)) => return Ok(HdrSource::from_bands(bands)),
        Some(ExrRead::Image(img)) => return Ok(HdrSource::from_image(img)),
        None => {}
    }
    // The part read: the first with R, G, B or Y channels (a renderer may put depth or
    // other outputs first); the first part when none has them (its error names it).
    let colour_part = meta
        .headers
        .iter()
        .position(|h| {
            let has = |n: &str| {
                h.channels
                    .list
                    .iter()
                    .any(|c| c.name.to_string().rsplit('.').next() == Some(n))
            };
            (has("R") && has("G") && has("B")) || has("Y")
        })
        .unwrap_or(0);
    // The other layouts, and files the block reader found irregular: the exr crate's image
    // reader on this thread, so that a panic of its decompressors on damaged data (which on
    // its own thread pool would abort the process) is an error.
    let channels = || {
        read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
    };
    let layer = if colour_part == 0 {
        exr_guarded(path, || {
            channels()
                .first_valid_layer()
                .all_attributes()
                .non_parallel()
                .from_file(path)
        })?
        .layer_data
    } else {
        // Every part is decoded to reach a later one: their samples together must fit.
        let all: u64 = meta
            .headers
            .iter()
            .map(|h| {
                let px = (h.layer_size.width() as u64).saturating_mul(h.layer_size.height() as u64);
                px.saturating_mul(4 * h.channels.list.len() as u64)
            })
            .fold(0, u64::saturating_add);
        let size = meta.headers[colour_part].layer_size;
        let (w, h) = (size.width() as u64, size.height() as u64);
        let needed = all.saturating_add(w.saturating_mul(h).saturating_mul(DECODE_BYTES_PER_PIXEL));
        if needed > limits.max_bytes {
            return Err(Error::Memory {
                width: w,
                height: h,
                needed,
                max_bytes: limits.max_bytes,
            });
        }
        exr_guarded(path, || {
            channels()
                .all_layers()
                .all_attributes()
                .non_parallel()
                .from_file(path)
        })?
        .layer_data
        .into_iter()
        .nth(colour_part)
        .ok_or_else(|| Error::invalid("OpenEXR", "a part the header lists is missing", path))?
    };
    let (w, h) = (layer.size.width(), layer.size.height());
    let n = w * h;
    let find_channel = |name: &str| {
        layer.channel_data.list.iter().find(|c| {
            let full = c.name.to_string();
            full.rsplit('.').next() == Some(name)
        })
    };
    let (r, g, b) = match (find_channel("R"), find_channel("G"), find_channel("B")) {
        (Some(r), Some(g), Some(b)) => (r, g, b),
        _ => match find_channel("Y") {
            Some(y) => (y, y, y),
            None => {
                return Err(Error::Unsupported {
                    format: "OpenEXR",
                    message: "no R, G, B or Y channel in any part".into(),
                    path: path.into(),
                });
            }
        },
    };
    let len = |c: &exr::image::AnyChannel<FlatSamples>| c.sample_data.len();
    if len(r) != n || len(g) != n || len(b) != n {
        return Err(Error::Unsupported {
            format: "OpenEXR",
            message: "sub-sampled channels are not supported".into(),
            path: path.into(),
        });
    }
    // Interleave row by row in parallel, converting each sample as `values_as_f32` does.
    let mut data = vec![0.0f32; n * 3];
    {
        use rayon::prelude::*;
        let row = 3 * w.max(1);
        data.par_chunks_mut(row).enumerate().for_each(|(y, out)| {
            for (k, c) in [r, g, b].into_iter().enumerate() {
                let at = y * w;
                match &c.sample_data {
                    FlatSamples::F16(v) => {
                        for (o, s) in out[k..].iter_mut().step_by(3).zip(&v[at..at + w]) {
                            *o = s.to_f32();
                        }
                    }
                    FlatSamples::F32(v) => {
                        for (o, s) in out[k..].iter_mut().step_by(3).zip(&v[at..at + w]) {
                            *o = *s;
                        }
                    }
                    FlatSamples::U32(v) => {
                        for (o, s) in out[k..].iter_mut().step_by(3).zip(&v[at..at + w]) {
                            *o = *s as f32;
                        }
                    }
                }
            }
        });
    }
    Rgb32FImage::from_raw(w as u32, h as u32, data)
        .map(HdrSource::from_image)
        .ok_or_else(|| Error::invalid("OpenEXR", "image size overflows", path))
}

/// `read` (an exr crate image reader on this thread) with a panic of its decompressors on
/// damaged data made an error, as its errors are.
fn exr_guarded<T>(path: &Path, read: impl FnOnce() -> exr::error::Result<T>) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(read))
        .map_err(|_| Error::invalid("OpenEXR", "damaged data failed to decompress", path))?
        .map_err(|e| exr_error(e, path))
}

/// Refuses an OpenEXR header whose image a file of `file_len` bytes cannot hold, before the
/// image is allocated: every block takes at least 16 bytes (its offset in the table, its
/// position and its size), and a block's samples cannot be more than its compression's
/// largest ratio times its bytes (1 uncompressed; 128 for RLE, whose longest run is 127
/// bytes from 2; 4096 for ZIP, PIZ, PXR24 and B44, above deflate's 1032:1 and PIZ's
/// run-length Huffman codes of 255 values). DWA and HTJ2K, whose constant blocks shrink
/// further, are bounded by their block count only.
fn exr_fits_in_file(header: &exr::meta::header::Header, file_len: u64, path: &Path) -> Result<()> {
    use exr::compression::Compression as C;
    let blocks = header.chunk_count as u64;
    let least = blocks.saturating_mul(16);
    if least > file_len {
        return Err(Error::invalid(
            "OpenEXR",
            format!(
                "the header's {blocks} blocks need at least {least} bytes, the file holds \
                 {file_len} (truncated file or damaged header)"
            ),
            path,
        ));
    }
    if header.deep {
        return Ok(());
    }
    let ratio: u64 = match header.compression {
        C::Uncompressed => 1,
        C::RLE => 128,
        C::ZIP1 | C::ZIP16 | C::PIZ | C::PXR24 | C::B44 | C::B44A => 4096,
        _ => return Ok(()),
    };
    let (w, h) = (
        header.layer_size.width() as u64,
        header.layer_size.height() as u64,
    );
    let bytes = header
        .channels
        .list
        .iter()
        .map(|c| {
            let (sx, sy) = (c.sampling.0.max(1) as u64, c.sampling.1.max(1) as u64);
            (w / sx)
                .saturating_mul(h / sy)
                .saturating_mul(c.sample_type.bytes_per_sample() as u64)
        })
        .fold(0u64, u64::saturating_add);
    if bytes > ratio.saturating_mul(file_len) {
        return Err(Error::invalid(
            "OpenEXR",
            format!(
                "the header's {w}x{h} pixels are {bytes} bytes of samples, more than a file of \
                 {file_len} bytes holds ({}; truncated file or damaged header)",
                header.compression
            ),
            path,
        ));
    }
    Ok(())
}

/// The common OpenEXR layouts read block by block: one part of scan lines or of tiles (the
/// full-resolution level of mip-mapped files), every channel sampled at every pixel, R, G,
/// B (or Y) found as [`read_exr`] finds them. The compressed blocks are read in file order;
/// as soon as a band of the image is complete (a scan-line block, or a row of tiles), its
/// blocks are decompressed (PIZ by [`crate::piz`], ZIP by [`crate::exr_zip`], blocks stored
/// raw taken as they are, the other compressions by the exr crate) and converted straight
/// into the band's rows of the interleaved f32 image, or kept if `compact`: bands in
/// batches of at least 16 lines, in parallel on the caller's thread pool while the next
/// blocks are read. The
/// exr crate's image reader, which [`read_exr`] uses otherwise, decompresses in parallel
/// too, but on a thread pool it builds per file (none at all for uncompressed files) and
/// converts each sample through a per-line callback, which cost more than the
/// decompression here.
///
/// `Ok(None)` for every other layout (several parts, deep data, sub-sampled channels, no
/// R, G, B or Y, blocks missing or repeated), left to the exr crate's image reader and its
/// messages. Damaged blocks are errors.
fn read_exr_blocks(path: &Path, compact: bool) -> Result<Option<ExrRead>> {
    read_exr_blocks_by(path, compact, true)
}

/// [`read_exr_blocks`]; `at_offsets`: whether a regular file's blocks are read at the
/// offsets of its table ([`read_blocks_at_offsets`]) rather than in file order (the readers
/// do; the tests compare the two).
fn read_exr_blocks_by(path: &Path, compact: bool, at_offsets: bool) -> Result<Option<ExrRead>> {
    use exr::block::chunk::{Chunk, CompressedBlock};
    use exr::meta::BlockDescription;
    let file = File::open(path).map_err(|e| Error::io("cannot read", path, e))?;
    let reader = exr::block::read(std::io::BufReader::with_capacity(1 << 20, file), false)
        .map_err(|e| exr_error(e, path))?;
    let meta = reader.meta_data().clone();
    let [header] = meta.headers.as_slice() else {
        return Ok(None);
    };
    let list = &header.channels.list;
    if header.deep || list.iter().any(|c| c.sampling != exr::math::Vec2(1, 1)) {
        return Ok(None);
    }
    let find = |name: &str| {
        list.iter()
            .position(|c| c.name.to_string().rsplit('.').next() == Some(name))
    };
    let picked = match (find("R"), find("G"), find("B"), find("Y")) {
        (Some(r), Some(g), Some(b), _) => [r, g, b],
        (_, _, _, Some(y)) => [y, y, y],
        _ => return Ok(None),
    };
    let (w, h) = (header.layer_size.width(), header.layer_size.height());
    // The bands: their height and the blocks (columns of tiles) across each.
    let (band, across, tile_w) = match header.blocks {
        BlockDescription::ScanLines => (header.compression.scan_lines_per_block(), 1, w),
        BlockDescription::Tiles(t) => (
            t.tile_size.height(),
            w.div_ceil(t.tile_size.width().max(1)),
            t.tile_size.width(),
        ),
    };
    if w == 0 || h == 0 || band == 0 || tile_w == 0 {
        return Ok(None);
    }
    let too_large = || Error::invalid("OpenEXR", "image size overflows", path);
    if u32::try_from(w).is_err() || u32::try_from(h).is_err() {
        return Err(too_large());
    }
    let layout = Layout {
        w,
        picked,
        types: list.iter().map(|c| c.sample_type).collect(),
        piz: header.compression == exr::compression::Compression::PIZ,
        zip: matches!(
            header.compression,
            exr::compression::Compression::ZIP1 | exr::compression::Compression::ZIP16
        ),
    };
    let bands = h.div_ceil(band);
    // Files whose offset table and blocks are regular: every block read at its offset by
    // the pool's threads.
    if at_offsets
        && let Some(read) = read_blocks_at_offsets(
            path,
            header,
            &meta,
            &layout,
            compact,
            (band, across, tile_w),
        )
    {
        return Ok(Some(match read {
            OffsetRead::Image(data) => ExrRead::Image(
                Rgb32FImage::from_raw(w as u32, h as u32, data).ok_or_else(too_large)?,
            ),
            OffsetRead::Bands(bands, row_stats) => ExrRead::Bands(ExrBands {
                layout,
                band,
                h,
                bands,
                row_stats,
            }),
        }));
    }
    // Otherwise each band's blocks are decompressed (and converted into the image's rows,
    // unless `compact`) as soon as they are read in file order: the reading overlaps the
    // decoding. A block missing or given twice leaves the file to the exr crate.
    let mut done: Vec<Vec<ExrBlock>> = (0..bands).map(|_| Vec::new()).collect();
    let mut data = if compact {
        Vec::new()
    } else {
        vec![0.0f32; 3 * w * h]
    };
    let mut slots: Vec<Option<BandSlot>> = if compact {
        done.iter_mut().map(|b| Some(BandSlot::Blocks(b))).collect()
    } else {
        data.chunks_mut(3 * w * band)
            .map(|r| Some(BandSlot::Rows(r)))
            .collect()
    };
    // Each band's blocks read so far: (chunk number in the file, column, chunk).
    let mut pending: Vec<Vec<(usize, usize, Chunk)>> = (0..bands).map(|_| Vec::new()).collect();
    let mut open = bands;
    // The error of the first chunk in file order that failed (whichever thread saw it
    // first), so that a damaged file always gives the same message.
    let failed: std::sync::Mutex<Option<(usize, Error)>> = std::sync::Mutex::new(None);
    let fail = |i: usize, e: Error| {
        let mut f = failed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if f.as_ref().is_none_or(|(j, _)| i < *j) {
            *f = Some((i, e));
        }
    };
    let mut irregular = false;
    // Complete bands not yet given to the pool, and their lines.
    let mut batch = Vec::new();
    let mut batch_lines = 0;
    const BATCH_LINES: usize = 16;
    let chunks = reader.all_chunks(false).map_err(|e| exr_error(e, path))?;
    rayon::scope(|scope| {
        let (layout, meta, fail) = (&layout, &meta, &fail);
        // Decodes a batch of complete bands on the pool.
        let flush = |batch: Vec<_>| {
            scope.spawn(move |_| {
                let mut planes = <[Vec<f32>; 3]>::default();
                for (slot, blocks, lines) in batch {
                    let mut blocks: Vec<(usize, usize, Chunk)> = blocks;
                    blocks.sort_by_key(|b| b.1);
                    let mut slot = slot;
                    let mut kept = Vec::new();
                    for (i, column, chunk) in blocks {
                        let x0 = column * tile_w;
                        let cols = tile_w.min(w - x0);
                        let mut b = match layout.decompress(meta, chunk, x0, cols, lines, path) {
                            Ok(b) => b,
                            // The band's other blocks are not needed; the batch's other
                            // bands are decoded still, so that the first failing block in
                            // file order is always found.
                            Err(e) => {
                                fail(i, e);
                                break;
                            }
                        };
                        match &mut slot {
                            // Converted while the block is in the cache.
                            BandSlot::Rows(rows) => layout.block_into(&b, rows, &mut planes),
                            // Kept: whether its rows need the dirty-input rule.
                            BandSlot::Blocks(_) => {
                                b.clean = layout.is_clean(&b.samples, b.cols, b.lines);
                                kept.push(b);
                            }
                        }
                    }
                    if let BandSlot::Blocks(out) = slot {
                        *out = kept;
                    }
                }
            });
        };
        for (i, chunk) in chunks.enumerate() {
            let chunk = match chunk {
                Ok(c) => c,
                Err(e) => {
                    fail(i, exr_error(e, path));
                    break;
                }
            };
            // The band and the block's column in it; blocks of smaller mip levels are
            // skipped.
            let (at, column) = match &chunk.compressed_block {
                CompressedBlock::Tile(t) if t.coordinates.level_index != exr::math::Vec2(0, 0) => {
                    continue;
                }
                CompressedBlock::Tile(t) => {
                    (t.coordinates.tile_index.y(), t.coordinates.tile_index.x())
                }
                _ => match header.get_block_data_indices(&chunk.compressed_block) {
                    Ok(t) => (t.tile_index.y(), 0),
                    Err(e) => {
                        fail(i, exr_error(e, path));
                        break;
                    }
                },
            };
            let Some(blocks) = pending.get_mut(at) else {
                irregular = true;
                break;
            };
            if chunk.layer_index != 0 || column >= across {
                irregular = true;
                break;
            }
            // A block of a band already decoded is a repeat too: damaged (OpenEXR's library
            // refuses it), not a layout for the exr crate, which would leave zeros where
            // the block that is missing belongs.
            if slots[at].is_none() || blocks.iter().any(|b| b.1 == column) {
                fail(
                    i,
                    Error::invalid(
                        "OpenEXR",
                        format!("block {i} repeats the block of band {at}, column {column}"),
                        path,
                    ),
                );
                break;
            }
            blocks.push((i, column, chunk));
            if blocks.len() < across {
                continue;
            }
            let Some(slot) = slots[at].take() else {
                irregular = true;
                break;
            };
            let lines = band.min(h - at * band);
            batch.push((slot, std::mem::take(blocks), lines));
            batch_lines += lines;
            open -= 1;
            // Bands go to the pool in batches of at least `BATCH_LINES` lines (single-line
            // blocks one task each kept the other threads waking for a few microseconds
            // of work).
            if batch_lines < BATCH_LINES && open > 0 {
                continue;
            }
            batch_lines = 0;
            flush(std::mem::take(&mut batch));
            // Every band taken: the rest of the file holds smaller mip levels only, which
            // need not be read (nor be intact).
            if open == 0 {
                break;
            }
        }
        // The bands complete when the loop stopped are decoded still (their errors may
        // come first in the file).
        if !batch.is_empty() {
            flush(std::mem::take(&mut batch));
        }
    });
    if let Some((_, e)) = failed
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
    {
        return Err(e);
    }
    if irregular || slots.iter().any(Option::is_some) {
        return Ok(None);
    }
    if !compact {
        return Ok(Some(ExrRead::Image(
            Rgb32FImage::from_raw(w as u32, h as u32, data).ok_or_else(too_large)?,
        )));
    }
    Ok(Some(ExrRead::Bands(ExrBands {
        layout,
        band,
        h,
        bands: done,
        row_stats: Vec::new(),
    })))
}

/// What [`read_blocks_at_offsets`] read.
enum OffsetRead {
    /// The image's samples (RGB).
    Image(Vec<f32>),
    /// Each band's blocks, from left to right, and every row's first-pass statistics.
    Bands(Vec<Vec<ExrBlock>>, Vec<crate::rows::RowStats>),
}

/// The full-resolution blocks of a single-part file (scan lines, or tiles `tile_w` wide,
/// `across` to a band) read at the offsets its table gives, each by a positioned read on
/// one of the pool's threads, and decompressed there (then converted into the image's rows,
/// unless `compact`). The file-order reader reads every block on one thread: an
/// uncompressed 8-megapixel float image, whose blocks need no decoding, spent half its
/// `tonemap` run reading. `None` for anything irregular (an offset table or a block that is
/// not where, or what, the header says, a block that fails to decompress, a failed read):
/// the file-order reader then reads the file and finds the first error in file order, as
/// it always has.
#[cfg(unix)]
fn read_blocks_at_offsets(
    path: &Path,
    header: &exr::meta::header::Header,
    meta: &exr::meta::MetaData,
    layout: &Layout,
    compact: bool,
    (band, across, tile_w): (usize, usize, usize),
) -> Option<OffsetRead> {
    use exr::block::chunk::{
        Chunk, CompressedBlock, CompressedScanLineBlock, CompressedTileBlock, TileCoordinates,
    };
    use exr::math::Vec2;
    use rayon::prelude::*;
    use std::os::unix::fs::FileExt;
    let tiled = matches!(header.blocks, exr::meta::BlockDescription::Tiles(_));
    let file = File::open(path).ok()?;
    let len = file.metadata().ok()?.len();
    let (w, h) = (layout.w, header.layer_size.height());
    let bands = h.div_ceil(band);
    // The full-resolution blocks come first in the table (smaller mip levels after them).
    let blocks = bands.checked_mul(across)?;
    if header.chunk_count < blocks || (!tiled && header.chunk_count != blocks) {
        return None;
    }
    let mut table = vec![0u8; blocks.checked_mul(8)?];
    file.read_exact_at(&mut table, exr_header_end(&file, len, tiled)?)
        .ok()?;
    let offsets: Vec<u64> = table
        .chunks_exact(8)
        .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
        .collect();
    let y0 = i64::from(header.own_attributes.layer_position.y());
    let max_block = header.max_block_byte_size() as u64;
    // Block `column` of band `at`.
    let read_block = |at: usize, column: usize| -> Option<ExrBlock> {
        let offset = offsets[at * across + column];
        // A scan-line block's first line and size; a tile's column, row, level (x, y) and
        // size.
        let mut head = [0u8; 20];
        let head = &mut head[..if tiled { 20 } else { 8 }];
        file.read_exact_at(head, offset).ok()?;
        let mut fields = [0i32; 5];
        for (f, b) in fields.iter_mut().zip(head.as_chunks::<4>().0) {
            *f = i32::from_le_bytes(*b);
        }
        let (&size, place) = fields[..head.len() / 4].split_last()?;
        let size = u64::try_from(size).ok()?;
        let expected: [i64; 4] = [column as i64, at as i64, 0, 0];
        let here = if tiled {
            place.iter().map(|&v| i64::from(v)).eq(expected)
        } else {
            i64::from(place[0]) == y0 + (at * band) as i64
        };
        // The block where the table says, its data inside the file and no larger than the
        // block's samples uncompressed (the exr crate's bound: blocks whose sizes ran to the
        // end of the file, overlapping the next ones, would each be read whole).
        let start = offset.checked_add(head.len() as u64)?;
        if !here || start.checked_add(size)? > len || size > max_block {
            return None;
        }
        let mut data = vec![0u8; usize::try_from(size).ok()?];
        file.read_exact_at(&mut data, start).ok()?;
        let compressed_block = if tiled {
            CompressedBlock::Tile(CompressedTileBlock {
                coordinates: TileCoordinates {
                    tile_index: Vec2(column, at),
                    level_index: Vec2(0, 0),
                },
                compressed_pixels_le: data,
            })
        } else {
            CompressedBlock::ScanLine(CompressedScanLineBlock {
                y_coordinate: place[0],
                compressed_pixels_le: data,
            })
        };
        let chunk = Chunk {
            layer_index: 0,
            compressed_block,
        };
        let x0 = column * tile_w;
        let cols = tile_w.min(w - x0);
        let lines = band.min(h - at * band);
        layout.decompress(meta, chunk, x0, cols, lines, path).ok()
    };
    // Tasks of at least 16 lines (the file-order reader's batches).
    let per_task = 16usize.div_ceil(band);
    // Band `at`'s blocks into `kept` (a band of tiles of half floats joined).
    let read_band = |at: usize, kept: &mut Vec<ExrBlock>| -> Option<()> {
        if across > 1 && layout.picks_halves() {
            let lines = band.min(h - at * band);
            let mut joined = vec![0u16; 3 * w * lines];
            for column in 0..across {
                layout.join_halves(&read_block(at, column)?, &mut joined);
            }
            let samples = BlockSamples::Halves(joined);
            let clean = layout.is_clean(&samples, w, lines);
            kept.push(ExrBlock {
                x0: 0,
                cols: w,
                lines,
                samples,
                clean,
            });
            return Some(());
        }
        for column in 0..across {
            let mut b = read_block(at, column)?;
            b.clean = layout.is_clean(&b.samples, b.cols, b.lines);
            kept.push(b);
        }
        Some(())
    };
    if compact {
        let mut out: Vec<Vec<ExrBlock>> = (0..bands).map(|_| Vec::new()).collect();
        let mut stats: Vec<Vec<crate::rows::RowStats>> = (0..bands).map(|_| Vec::new()).collect();
        out.par_iter_mut()
            .zip(stats.par_iter_mut())
            .enumerate()
            .with_min_len(per_task)
            .try_for_each_init(
                crate::rows::BandStats::default,
                |scratch, (at, (kept, st))| {
                    let lines = band.min(h - at * band);
                    read_band(at, kept)?;
                    *st = scratch.rows(
                        w,
                        at * band,
                        lines,
                        kept.iter().all(|b| b.clean),
                        |y, planes, row| {
                            for b in kept.iter() {
                                layout.line(b, y, planes, row);
                            }
                        },
                    );
                    Some(())
                },
            )?;
        #[cfg(test)]
        tests::READ_AT_OFFSETS.set(tests::READ_AT_OFFSETS.get() + 1);
        return Some(OffsetRead::Bands(out, stats.concat()));
    }
    let mut data = vec![0.0f32; 3 * w * h];
    data.par_chunks_mut(3 * w * band)
        .enumerate()
        .with_min_len(per_task)
        .try_for_each_init(<[Vec<f32>; 3]>::default, |planes, (at, rows)| {
            for column in 0..across {
                layout.block_into(&read_block(at, column)?, rows, planes);
            }
            Some(())
        })?;
    #[cfg(test)]
    tests::READ_AT_OFFSETS.set(tests::READ_AT_OFFSETS.get() + 1);
    Some(OffsetRead::Image(data))
}

#[cfg(not(unix))]
fn read_blocks_at_offsets(
    _: &Path,
    _: &exr::meta::header::Header,
    _: &exr::meta::MetaData,
    _: &Layout,
    _: bool,
    _: (usize, usize, usize),
) -> Option<OffsetRead> {
    None
}

/// Where the offset table of a single-part OpenEXR file starts: after its magic number,
/// its version field and its header's attributes (each a name, a type name, a 4-byte size
/// and that many bytes), which end with an empty name. `None` for deep and multi-part
/// files, for a file whose version field says it is tiled, or not, where `tiled` says
/// otherwise, and for a header longer than 1 MiB.
#[cfg(unix)]
pub(crate) fn exr_header_end(file: &File, len: u64, tiled: bool) -> Option<u64> {
    use std::os::unix::fs::FileExt;
    let mut buf = vec![0u8; usize::try_from(len.min(1 << 20)).ok()?];
    file.read_exact_at(&mut buf, 0).ok()?;
    let version = u32::from_le_bytes(buf.get(4..8)?.try_into().ok()?);
    // Bits 9, 11 and 12: single-part tiled, deep ("non-image") and multi-part files.
    if buf.get(..4)? != [0x76, 0x2f, 0x31, 0x01]
        || version & 0x1800 != 0
        || (version & 0x200 != 0) != tiled
    {
        return None;
    }
    let string_end = |at: usize| buf.get(at..)?.iter().position(|&b| b == 0).map(|n| at + n);
    let mut at = 8;
    loop {
        let name_end = string_end(at)?;
        if name_end == at {
            return Some(at as u64 + 1);
        }
        let type_end = string_end(name_end + 1)?;
        let size = u32::from_le_bytes(buf.get(type_end + 1..type_end + 5)?.try_into().ok()?);
        at = (type_end + 5).checked_add(usize::try_from(size).ok()?)?;
    }
}

/// Where a band's decoded blocks go.
enum BandSlot<'a> {
    /// Kept.
    Blocks(&'a mut Vec<ExrBlock>),
    /// Converted into the image's rows of the band.
    Rows(&'a mut [f32]),
}

/// What [`read_exr_blocks`] read.
enum ExrRead {
    Image(Rgb32FImage),
    Bands(ExrBands),
}

/// The decompressed blocks of an OpenEXR image ([`read_exr_blocks`]), band by band.
#[derive(Debug)]
struct ExrBands {
    layout: Layout,
    /// Lines per band (the last may have fewer).
    band: usize,
    /// Image height.
    h: usize,
    /// Each band's blocks, from left to right.
    bands: Vec<Vec<ExrBlock>>,
    /// Every row's statistics of the first tone-mapping pass, computed as each band was
    /// decoded (while its samples were in the cache); empty where not computed.
    row_stats: Vec<crate::rows::RowStats>,
}

impl ExrBands {
    /// Row `y` into `row` (RGB, the whole width).
    fn row(&self, y: usize, planes: &mut [Vec<f32>; 3], row: &mut [f32]) {
        for b in &self.bands[y / self.band] {
            self.layout.line(b, y % self.band, planes, row);
        }
    }

    /// Whether row `y`'s values are all finite and not negative ([`ExrBlock::clean`]).
    fn row_is_clean(&self, y: usize) -> bool {
        self.bands[y / self.band].iter().all(|b| b.clean)
    }
}

/// One decompressed block: the columns `x0..x0 + cols` of `lines` lines.
#[derive(Debug)]
struct ExrBlock {
    x0: usize,
    cols: usize,
    lines: usize,
    samples: BlockSamples,
    /// Whether every picked sample is finite and not negative (-0 allowed), by its bits:
    /// the dirty-input rule then changes nothing in the block's rows. Looked at only for
    /// the blocks a compact source keeps; `false` where not looked at (and for 32-bit
    /// samples of PIZ blocks).
    clean: bool,
}

/// A block's samples as decompressed.
#[derive(Debug)]
enum BlockSamples {
    /// Line after line, each channel's native-endian samples one after the other.
    Lines(Vec<u8>),
    /// The PIZ decoder's planes of indices into its values, except the picked half-float
    /// channels' planes, which hold the half values themselves (0 for indices past the
    /// values, which only damaged data has); where each channel's plane starts. The values
    /// are kept only where a picked channel is 32-bit.
    Piz {
        d: crate::piz::Decoded,
        first: Vec<usize>,
    },
    /// The picked channels' half floats, line after line, each line the R, G and B samples
    /// of the block's columns one channel after the other: a band of tiles joined
    /// ([`Layout::join_halves`]).
    Halves(Vec<u16>),
}

/// What [`read_exr_blocks`] needs to decode a block.
#[derive(Debug)]
struct Layout {
    /// Image width.
    w: usize,
    /// The channels read as R, G, B.
    picked: [usize; 3],
    /// Every channel's sample type, in the file's (sorted) order.
    types: Vec<exr::meta::attribute::SampleType>,
    /// Whether the blocks are PIZ-compressed.
    piz: bool,
    /// Whether they are ZIP-compressed (one line or sixteen per block).
    zip: bool,
}

impl Layout {
    /// Decompresses `chunk`, the block of columns `x0..x0 + cols` of a band of `lines`.
    fn decompress(
        &self,
        meta: &exr::meta::MetaData,
        mut chunk: exr::block::chunk::Chunk,
        x0: usize,
        cols: usize,
        lines: usize,
        path: &Path,
    ) -> Result<ExrBlock> {
        use exr::block::UncompressedBlock;
        use exr::block::chunk::CompressedBlock;
        let sizes = self.types.iter().map(|t| t.bytes_per_sample());
        let line_bytes = cols * sizes.sum::<usize>();
        let block = |samples| ExrBlock {
            x0,
            cols,
            lines,
            clean: false,
            samples,
        };
        let pixels = match &mut chunk.compressed_block {
            CompressedBlock::ScanLine(b) => &mut b.compressed_pixels_le,
            CompressedBlock::Tile(t) => &mut t.compressed_pixels_le,
            _ => return Err(Error::invalid("OpenEXR", "deep data in a flat image", path)),
        };
        let expected = lines * line_bytes;
        if cfg!(target_endian = "little") {
            // A block of the block's size holds its samples as they are (uncompressed, or
            // not smaller compressed: the exr crate's rule), little-endian like this machine.
            if pixels.len() == expected {
                return Ok(block(BlockSamples::Lines(std::mem::take(pixels))));
            }
            if self.zip {
                let data = crate::exr_zip::decompress(pixels, expected)
                    .map_err(|e| Error::invalid("OpenEXR", e, path))?;
                return Ok(block(BlockSamples::Lines(data)));
            }
        }
        // PIZ through `piz` (a block stored raw, when compressing did not shrink it, goes
        // the general way).
        if self.piz && pixels.len() != expected {
            let words: Vec<usize> = self
                .types
                .iter()
                .map(|t| t.bytes_per_sample() / 2)
                .collect();
            let mut d = crate::piz::decompress(pixels, &words, cols, lines)
                .map_err(|e| Error::invalid("OpenEXR", e, path))?;
            let mut first = Vec::with_capacity(words.len());
            let mut at = 0;
            for &k in &words {
                first.push(at);
                at += k * cols * lines;
            }
            // Half samples: each index replaced by its value once, so that every conversion
            // of a line to f32 is a vector one (F16C) rather than a lookup per sample.
            // The values are a table of every 16-bit index (0 past the values that occur),
            // so the lookup needs no bounds check.
            let table: &[u16; 1 << 16] = d
                .values
                .as_slice()
                .try_into()
                .map_err(|_| Error::invalid("OpenEXR", "PIZ value table size", path))?;
            let mut mapped = Vec::with_capacity(3);
            for &c in &self.picked {
                if words[c] == 1 && !mapped.contains(&c) {
                    let plane = &mut d.planes[first[c]..first[c] + cols * lines];
                    for i in plane {
                        *i = table[usize::from(*i)];
                    }
                    mapped.push(c);
                }
            }
            // Every picked channel holds its values now: the table (128 KiB a block, which
            // small tiles would keep by the thousand) is not kept.
            if self.picked.iter().all(|&c| words[c] == 1) {
                d.recycle_values();
            }
            return Ok(block(BlockSamples::Piz { d, first }));
        }
        // The exr crate's decompressors can panic on damaged data (B44's arithmetic
        // overflows where overflow is checked): a panic is the block's error.
        let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            UncompressedBlock::decompress_chunk(chunk, meta, false)
        }))
        .map_err(|_| Error::invalid("OpenEXR", "a damaged block failed to decompress", path))?
        .map_err(|e| exr_error(e, path))?;
        if decoded.data.len() != expected {
            return Err(Error::invalid(
                "OpenEXR",
                "a block's data does not match its size",
                path,
            ));
        }
        Ok(block(BlockSamples::Lines(decoded.data)))
    }

    /// Whether every picked sample of `samples` (a block of `cols` by `lines`) is finite and
    /// not negative, by its bits ([`ExrBlock::clean`]).
    fn is_clean(&self, samples: &BlockSamples, cols: usize, lines: usize) -> bool {
        use exr::meta::attribute::SampleType;
        // A half or a float that is NaN, infinite or below -0. (`&` folds, which
        // vectorise, rather than `all`, which stops early.)
        let half = |h: u16| (h & 0x7fff) < 0x7c00 && h <= 0x8000;
        let float = |f: u32| (f & 0x7fff_ffff) < 0x7f80_0000 && f <= 0x8000_0000;
        match samples {
            BlockSamples::Halves(h) => h.iter().fold(true, |ok, &v| ok & half(v)),
            BlockSamples::Piz { d, first } => self.picked.iter().all(|&c| {
                self.types[c] == SampleType::F16
                    && d.planes[first[c]..first[c] + cols * lines]
                        .iter()
                        .fold(true, |ok, &h| ok & half(h))
            }),
            BlockSamples::Lines(data) => {
                let line_bytes: usize =
                    self.types.iter().map(|t| cols * t.bytes_per_sample()).sum();
                data.chunks_exact(line_bytes.max(1)).all(|line| {
                    self.picked.iter().all(|&c| {
                        let bytes = &line[self.channel_in_line(c, cols)];
                        match self.types[c] {
                            SampleType::F16 => bytes
                                .as_chunks::<2>()
                                .0
                                .iter()
                                .fold(true, |ok, b| ok & half(u16::from_ne_bytes(*b))),
                            SampleType::F32 => bytes
                                .as_chunks::<4>()
                                .0
                                .iter()
                                .fold(true, |ok, b| ok & float(u32::from_ne_bytes(*b))),
                            SampleType::U32 => true,
                        }
                    })
                })
            }
        }
    }

    /// Where channel `c`'s samples lie within a line of a block `cols` wide (each channel's
    /// samples one after the other, in the file's order).
    fn channel_in_line(&self, c: usize, cols: usize) -> std::ops::Range<usize> {
        let at: usize = self.types[..c]
            .iter()
            .map(|t| cols * t.bytes_per_sample())
            .sum();
        at..at + cols * self.types[c].bytes_per_sample()
    }

    /// Every line of block `b` into its columns of its band's `rows` (RGB, the whole width).
    fn block_into(&self, b: &ExrBlock, rows: &mut [f32], planes: &mut [Vec<f32>; 3]) {
        for (y, row) in rows.chunks_exact_mut(3 * self.w).enumerate() {
            self.line(b, y, planes, row);
        }
    }

    /// Whether every picked channel holds half floats.
    fn picks_halves(&self) -> bool {
        use exr::meta::attribute::SampleType;
        self.picked
            .iter()
            .all(|&c| self.types[c] == SampleType::F16)
    }

    /// Line `y` of block `b` as the picked channels' half floats (native-endian bytes, R,
    /// G and B), where every picked channel is half.
    fn half_lines<'b>(&self, b: &'b ExrBlock, y: usize) -> Option<[&'b [u8]; 3]> {
        let cols = b.cols;
        match &b.samples {
            BlockSamples::Halves(h) => {
                let line = &h[3 * y * cols..3 * (y + 1) * cols];
                let (r, gb) = line.split_at(cols);
                let (g, bl) = gb.split_at(cols);
                Some([r, g, bl].map(bytemuck::cast_slice))
            }
            _ if !self.picks_halves() => None,
            BlockSamples::Piz { d, first } => Some(
                self.picked
                    .map(|c| bytemuck::cast_slice(&d.planes[first[c] + y * cols..][..cols])),
            ),
            BlockSamples::Lines(data) => {
                let line_bytes = data.len() / b.lines;
                let line = &data[y * line_bytes..(y + 1) * line_bytes];
                Some(self.picked.map(|c| &line[self.channel_in_line(c, cols)]))
            }
        }
    }

    /// Block `b`'s picked half floats copied into their columns of `joined`, the lines of
    /// its band as [`BlockSamples::Halves`] holds them (the image's width), where every
    /// picked channel is half. Tiles joined so are read as one block: a row of the image is
    /// then three runs of samples, not three short ones per tile (the two passes of a
    /// tone-mapping curve over an 8-megapixel image of 64 x 64 tiles spent a tenth of their
    /// time gathering them).
    fn join_halves(&self, b: &ExrBlock, joined: &mut [u16]) {
        let w = self.w;
        for (y, line) in joined.chunks_exact_mut(3 * w).take(b.lines).enumerate() {
            if let Some(src) = self.half_lines(b, y) {
                for (c, s) in src.iter().enumerate() {
                    let to = &mut line[c * w + b.x0..][..b.cols];
                    bytemuck::cast_slice_mut::<u16, u8>(to).copy_from_slice(s);
                }
            }
        }
    }

    /// Line `y` of block `b` into its columns of `row` (RGB, the whole width); `planes`:
    /// three buffers of at least the block's width.
    fn line(&self, b: &ExrBlock, y: usize, planes: &mut [Vec<f32>; 3], row: &mut [f32]) {
        use exr::meta::attribute::SampleType;
        let cols = b.cols;
        let out = &mut row[3 * b.x0..3 * (b.x0 + cols)];
        // Three half-float channels: converted and interleaved in one step.
        if let Some([r, g, bl]) = self.half_lines(b, y) {
            halves_to_rgb(r, g, bl, out);
            return;
        }
        for p in planes.iter_mut() {
            p.resize(cols, 0.0);
        }
        match &b.samples {
            BlockSamples::Piz { d, first } => {
                for (plane, &c) in planes.iter_mut().zip(&self.picked) {
                    let k = self.types[c].bytes_per_sample() / 2;
                    let line = &d.planes[first[c] + y * k * cols..first[c] + (y + 1) * k * cols];
                    if k == 1 {
                        halves_to_f32(bytemuck::cast_slice(line), plane);
                    } else {
                        let value = |i: u16| u32::from(d.values[usize::from(i)]);
                        let pairs = line.as_chunks::<2>().0.iter();
                        let bits = pairs.map(|p| value(p[0]) | value(p[1]) << 16);
                        if self.types[c] == SampleType::U32 {
                            for (o, v) in plane.iter_mut().zip(bits) {
                                *o = v as f32;
                            }
                        } else {
                            for (o, v) in plane.iter_mut().zip(bits) {
                                *o = f32::from_bits(v);
                            }
                        }
                    }
                }
            }
            BlockSamples::Lines(data) => {
                let line_bytes = data.len() / b.lines;
                let line = &data[y * line_bytes..(y + 1) * line_bytes];
                for (plane, &c) in planes.iter_mut().zip(&self.picked) {
                    samples_to_f32(self.types[c], &line[self.channel_in_line(c, cols)], plane);
                }
            }
            // Converted above.
            BlockSamples::Halves(_) => return,
        }
        let [r, g, bl] = &*planes;
        for (((o, r), g), bl) in out.as_chunks_mut::<3>().0.iter_mut().zip(r).zip(g).zip(bl) {
            *o = [*r, *g, *bl];
        }
    }
}

/// Converts one channel's native-endian samples of one line to f32 (`values_as_f32`'s
/// conversion): half floats a vector at a time where the CPU converts them (F16C).
fn samples_to_f32(ty: exr::meta::attribute::SampleType, src: &[u8], out: &mut [f32]) {
    use exr::meta::attribute::SampleType;
    match ty {
        SampleType::F16 => halves_to_f32(src, out),
        SampleType::F32 => {
            for (o, b) in out.iter_mut().zip(src.as_chunks::<4>().0) {
                *o = f32::from_ne_bytes(*b);
            }
        }
        SampleType::U32 => {
            for (o, b) in out.iter_mut().zip(src.as_chunks::<4>().0) {
                *o = u32::from_ne_bytes(*b) as f32;
            }
        }
    }
}

/// Half floats (native-endian, two bytes each) to f32, exactly: eight at a time with F16C
/// where the CPU has it (the `half` crate's slice conversion called a function per eight
/// values, which cost more than the conversion), one at a time otherwise.
fn halves_to_f32(src: &[u8], out: &mut [f32]) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("f16c") && std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: F16C and AVX detected just above.
        #[allow(unsafe_code)]
        unsafe {
            done = halves_to_f32_f16c(src, out);
        }
    }
    for (o, b) in out[done..]
        .iter_mut()
        .zip(src[2 * done..].as_chunks::<2>().0)
    {
        *o = half::f16::from_bits(u16::from_ne_bytes(*b)).to_f32();
    }
}

/// Three channels of half floats (native-endian, two bytes each, the same count) to
/// interleaved RGB f32 in `out`: [`halves_to_f32`]'s conversion, eight pixels at a time with
/// F16C where the CPU has it.
fn halves_to_rgb(r: &[u8], g: &[u8], b: &[u8], out: &mut [f32]) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("f16c") && std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: F16C and AVX detected just above.
        #[allow(unsafe_code)]
        unsafe {
            done = halves_to_rgb_f16c(r, g, b, out);
        }
    }
    let half =
        |s: &[u8], i: usize| half::f16::from_bits(u16::from_ne_bytes([s[2 * i], s[2 * i + 1]]));
    for (i, o) in out.as_chunks_mut::<3>().0.iter_mut().enumerate().skip(done) {
        *o = [
            half(r, i).to_f32(),
            half(g, i).to_f32(),
            half(b, i).to_f32(),
        ];
    }
}

/// [`halves_to_rgb`]'s whole groups of eight pixels; how many pixels it did.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
fn halves_to_rgb_f16c(r: &[u8], g: &[u8], b: &[u8], out: &mut [f32]) -> usize {
    use std::arch::x86_64::{__m128i, _mm256_cvtph_ps};
    let eight = |s: &[u8; 16]| -> [f32; 8] {
        bytemuck::cast(_mm256_cvtph_ps(bytemuck::cast::<[u8; 16], __m128i>(*s)))
    };
    let (r8, g8, b8) = (
        r.as_chunks::<16>().0,
        g.as_chunks::<16>().0,
        b.as_chunks::<16>().0,
    );
    let o24 = out.as_chunks_mut::<24>().0;
    let n = r8.len().min(g8.len()).min(b8.len()).min(o24.len());
    for (((r, g), b), o) in r8.iter().zip(g8).zip(b8).zip(o24.iter_mut()) {
        let (r, g, b) = (eight(r), eight(g), eight(b));
        for j in 0..8 {
            o[3 * j] = r[j];
            o[3 * j + 1] = g[j];
            o[3 * j + 2] = b[j];
        }
    }
    8 * n
}

/// [`halves_to_f32`]'s whole groups of eight; how many values it did.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
fn halves_to_f32_f16c(src: &[u8], out: &mut [f32]) -> usize {
    use std::arch::x86_64::{__m128i, _mm256_cvtph_ps};
    let (from, to) = (src.as_chunks::<16>().0, out.as_chunks_mut::<8>().0);
    let n = from.len().min(to.len());
    for (s, o) in from.iter().zip(to.iter_mut()) {
        *o = bytemuck::cast(_mm256_cvtph_ps(bytemuck::cast::<[u8; 16], __m128i>(*s)));
    }
    8 * n
}

/// Reads a Radiance RGBE file. Header lines before the `#?RADIANCE` magic (real files
/// start with a `VIEW=` line, like Debevec's memorial.hdr) are skipped.
///
/// # Errors
/// As [`read_hdr_image_with`].
pub fn read_radiance(path: &Path, limits: &Limits) -> Result<Rgb32FImage> {
    Ok(read_radiance_source(path, limits)?.into_image())
}

/// An HDR image as compact as its file allows, decoded one row at a time: a Radiance file
/// whose scan lines are run-length encoded (what current writers produce) keeps its own
/// bytes (about a sixth of the `f32` image for typical files); an OpenEXR file the block
/// reader takes keeps its blocks decompressed (half floats stay half); every other file is
/// the decoded image. A global tone-mapping curve runs over it in two passes of rows (the
/// statistics, then the display codes) without the `f32` image or its luminance plane:
/// [`crate::Operator::apply_rows`].
#[derive(Debug)]
pub struct HdrSource {
    width: u32,
    height: u32,
    inner: Source,
}

#[derive(Debug)]
enum Source {
    /// The file's bytes, and where each scan line's data starts.
    Rgbe {
        data: Vec<u8>,
        starts: Vec<usize>,
    },
    /// OpenEXR blocks decompressed, samples as the file stores them.
    Exr(ExrBands),
    Image(Rgb32FImage),
}

/// One thread's buffers for [`HdrSource::decode_row`].
#[derive(Clone, Debug, Default)]
pub struct RowScratch {
    bytes: Vec<u8>,
    planes: [Vec<f32>; 3],
}

impl HdrSource {
    /// Wraps an image already decoded.
    #[must_use]
    pub fn from_image(img: Rgb32FImage) -> Self {
        Self {
            width: img.width(),
            height: img.height(),
            inner: Source::Image(img),
        }
    }

    /// An OpenEXR image's decompressed blocks (sizes checked by [`read_exr_blocks`]).
    fn from_bands(bands: ExrBands) -> Self {
        Self {
            width: bands.layout.w as u32,
            height: bands.h as u32,
            inner: Source::Exr(bands),
        }
    }

    /// Width and height in pixels.
    #[must_use]
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Every row's first-pass statistics, where they were computed as the source was
    /// decoded (OpenEXR blocks read at their offsets).
    pub(crate) fn row_stats(&self) -> Option<&[crate::rows::RowStats]> {
        match &self.inner {
            Source::Exr(bands) if !bands.row_stats.is_empty() => Some(&bands.row_stats),
            _ => None,
        }
    }

    /// Whether the pixels are held as the file's compact encoding (not as `f32`).
    #[must_use]
    pub fn is_compact(&self) -> bool {
        !matches!(self.inner, Source::Image(_))
    }

    /// Row `y` as RGB `f32` into `out` (`3 * width` values); `scratch` holds buffers the
    /// caller keeps between calls (one per thread). The values are those of
    /// [`HdrSource::into_image`], bit for bit.
    ///
    /// # Panics
    /// If `y` is not a row of the image or `out` is not one row long.
    pub fn decode_row(&self, y: usize, scratch: &mut RowScratch, out: &mut [f32]) {
        let row = 3 * self.width as usize;
        assert_eq!(out.len(), row, "one row of RGB values");
        match &self.inner {
            Source::Rgbe { data, starts } => {
                scratch.bytes.resize(4 * self.width as usize, 0);
                decode_rgbe_row(data, starts[y], &mut scratch.bytes, out);
            }
            Source::Exr(bands) => bands.row(y, &mut scratch.planes, out),
            Source::Image(img) => out.copy_from_slice(&img.as_raw()[y * row..(y + 1) * row]),
        }
    }

    /// Row `y`'s luminance ([`crate::luminance`] of [`HdrSource::decode_row`]'s values,
    /// bit for bit) into `out` (`width` values), for an RGBE source; `false` (nothing
    /// written) for the others, whose values must be cleaned first.
    pub(crate) fn luminance_row(
        &self,
        y: usize,
        scratch: &mut RowScratch,
        out: &mut [f32],
    ) -> bool {
        match &self.inner {
            Source::Rgbe { data, starts } => {
                scratch.bytes.resize(4 * self.width as usize, 0);
                rgbe_luminance_row(data, starts[y], &mut scratch.bytes, out);
                true
            }
            Source::Exr(_) | Source::Image(_) => false,
        }
    }

    /// Whether row `y`'s values are known to be finite and not negative (RGBE values
    /// always; OpenEXR blocks checked as decompressed), so the dirty-input rule would
    /// change nothing.
    pub(crate) fn row_is_clean(&self, y: usize) -> bool {
        match &self.inner {
            Source::Rgbe { .. } => true,
            Source::Exr(bands) => bands.row_is_clean(y),
            Source::Image(_) => false,
        }
    }

    /// The decoded image (rows in parallel for a compact source).
    #[must_use]
    pub fn into_image(self) -> Rgb32FImage {
        use rayon::prelude::*;
        match self.inner {
            Source::Image(img) => img,
            Source::Rgbe { data, starts } => {
                let (w, h) = (self.width as usize, self.height as usize);
                let mut out = vec![0.0f32; 3 * w * h];
                out.par_chunks_mut(3 * w)
                    .zip(starts.par_iter())
                    .for_each_init(
                        || vec![0u8; 4 * w],
                        |planes, (row, &at)| decode_rgbe_row(&data, at, planes, row),
                    );
                Rgb32FImage::from_raw(self.width, self.height, out)
                    .expect("buffer size matches dimensions")
            }
            Source::Exr(bands) => {
                let w = self.width as usize;
                let mut out = vec![0.0f32; 3 * w * self.height as usize];
                let (layout, band) = (&bands.layout, bands.band);
                // Band by band, each band's blocks freed once converted.
                out.par_chunks_mut(3 * w * band)
                    .zip(bands.bands.into_par_iter())
                    .for_each_init(<[Vec<f32>; 3]>::default, |planes, (rows, blocks)| {
                        for b in &blocks {
                            layout.block_into(b, rows, planes);
                        }
                    });
                Rgb32FImage::from_raw(self.width, self.height, out)
                    .expect("buffer size matches dimensions")
            }
        }
    }
}

/// Reads an HDR image as an [`HdrSource`]: compact for run-length encoded Radiance files
/// and for OpenEXR files the block reader takes (one flat part with R, G, B or Y), decoded
/// otherwise (as [`read_hdr_image_with`]).
///
/// # Errors
/// As [`read_hdr_image_with`].
pub fn read_hdr_source_with(path: impl AsRef<Path>, limits: &Limits) -> Result<HdrSource> {
    let path = path.as_ref();
    match detect_format(path)? {
        HdrFormat::Radiance => read_radiance_source(path, limits),
        HdrFormat::Exr => read_exr_source(path, limits, true),
        HdrFormat::Pfm => read_pfm(path, limits).map(HdrSource::from_image),
    }
}

/// The whole file, as `std::fs::read` gives it. Large files on Unix are read in pieces by
/// the pool's threads at once (positioned reads into their own parts of the buffer): the
/// kernel's copy into fresh pages was a tenth of a serial `tonemap` run of an 8-megapixel
/// Radiance file. A file that changes length while read is an error.
fn read_whole_file(path: &Path) -> std::io::Result<Vec<u8>> {
    #[cfg(unix)]
    {
        use rayon::prelude::*;
        use std::os::unix::fs::FileExt;
        const PIECE: usize = 4 << 20;
        let file = File::open(path)?;
        let meta = file.metadata()?;
        let len = usize::try_from(meta.len()).unwrap_or(usize::MAX);
        if len >= 2 * PIECE && meta.is_file() {
            // Refused as `std::fs::read` refuses it when the memory is not there; then
            // zeroed pages from the system (no pass of zeroes before the reads).
            Vec::<u8>::new()
                .try_reserve_exact(len)
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::OutOfMemory, e))?;
            let mut buf = vec![0u8; len];
            buf.par_chunks_mut(PIECE)
                .enumerate()
                .try_for_each(|(i, piece)| file.read_exact_at(piece, (i * PIECE) as u64))?;
            // Nothing past the length read at the start.
            let mut more = [0u8; 1];
            if file.read_at(&mut more, len as u64)? != 0 {
                return Err(std::io::Error::other("the file grew while it was read"));
            }
            return Ok(buf);
        }
    }
    std::fs::read(path)
}

fn read_radiance_source(path: &Path, limits: &Limits) -> Result<HdrSource> {
    let bytes = read_whole_file(path).map_err(|e| Error::io("cannot read", path, e))?;
    let start = find(&bytes[..bytes.len().min(4096)], b"#?")
        .ok_or_else(|| Error::invalid("Radiance HDR", "no #? magic line in the header", path))?;
    let mut cursor = std::io::Cursor::new(&bytes[start..]);
    let decoder = image::codecs::hdr::HdrDecoder::new(&mut cursor)
        .map_err(|e| Error::invalid("Radiance HDR", e.to_string(), path))?;
    let (w, h) = decoder.dimensions();
    limits.check(u64::from(w), u64::from(h))?;
    drop(decoder);
    // The pixels start after the header's empty line and the resolution line; the fast path
    // is taken only where that agrees with where the image crate's decoder stopped reading.
    let data_at = radiance_data_start(&bytes, start);
    let read_to = usize::try_from(cursor.position())
        .ok()
        .and_then(|p| p.checked_add(start));
    let data_at = data_at.filter(|&at| Some(at) == read_to);
    if let Some(at) = data_at
        && let Some(mut starts) = rle_row_starts(&bytes[at..], w, h)
    {
        for s in &mut starts {
            *s += at;
        }
        return Ok(HdrSource {
            width: w,
            height: h,
            inner: Source::Rgbe {
                data: bytes,
                starts,
            },
        });
    }
    // Other scanline encodings (flat, the old run-length one) and damaged data: the image
    // crate's decoder, with its messages, once the data is known to hold every scan line
    // (the decoder allocates the whole image first, so a header that lies about the size
    // of a short file would cost that memory before the error).
    if let Some(at) = data_at
        && !radiance_scanlines_fit(&bytes[at..], w as usize, h as usize)
    {
        return Err(Error::invalid(
            "Radiance HDR",
            format!(
                "the data does not hold the header's {w}x{h} pixels (truncated or corrupt data?)"
            ),
            path,
        ));
    }
    let decoder = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(&bytes[start..]))
        .map_err(|e| Error::invalid("Radiance HDR", e.to_string(), path))?;
    let img = image::DynamicImage::from_decoder(decoder).map_err(|e| {
        Error::invalid(
            "Radiance HDR",
            format!("{e} (truncated or corrupt data?)"),
            path,
        )
    })?;
    Ok(HdrSource::from_image(img.into_rgb32f()))
}

/// Whether `data` holds `h` scan lines of `w` pixels as the image crate's decoder reads
/// them, without storing any: per scan line, the per-component run-length encoding (a
/// `2 2 <128 _` marker) or flat pixels with the old encoding's repeat markers (`1 1 1 n`, a
/// run of the previous pixel, `n` times 256 to the number of markers just before it). A
/// line that the decoder would refuse (a run past the line's end, a line that starts with a
/// repeat) is `false` too.
fn radiance_scanlines_fit(data: &[u8], w: usize, h: usize) -> bool {
    let mut pos = 0usize;
    for _ in 0..h {
        let Some(&[a, b, c, _]) = data.get(pos..pos + 4) else {
            return false;
        };
        pos += 4;
        if a == 2 && b == 2 && c < 128 {
            for _ in 0..4 {
                match skip_rle_component(data, pos, w) {
                    Some(end) => pos = end,
                    None => return false,
                }
            }
        } else {
            if [a, b, c] == [1, 1, 1] {
                return false;
            }
            let (mut x, mut mult) = (1usize, 1usize);
            while x < w {
                let Some(&[a, b, c, e]) = data.get(pos..pos + 4) else {
                    return false;
                };
                pos += 4;
                if [a, b, c] == [1, 1, 1] {
                    // Eight markers in a row would overflow the decoder's multiplier (256^8);
                    // four already count past any width the limits allow.
                    if mult > 1 << 48 {
                        return false;
                    }
                    let run = usize::from(e) * mult;
                    mult *= 256;
                    if x.saturating_add(run) > w {
                        return false;
                    }
                    x += run;
                } else {
                    mult = 1;
                    x += 1;
                }
            }
        }
    }
    true
}

/// Where one component of a run-length-encoded scan line of `w` pixels that starts at `pos`
/// ends, checked exactly as the image crate reads it (`None`: a run past the line's end, or
/// the data ends first).
fn skip_rle_component(data: &[u8], mut pos: usize, w: usize) -> Option<usize> {
    let mut x = 0usize;
    while x < w {
        let rl = usize::from(*data.get(pos)?);
        pos += 1;
        let n = if rl <= 128 { rl } else { rl - 128 };
        if x + n > w {
            return None;
        }
        pos += if rl <= 128 { rl } else { 1 };
        x += n;
    }
    (pos <= data.len()).then_some(pos)
}

/// Where a Radiance file's pixel data starts: past its first line (the `#?` signature), the
/// header lines up to the first empty one, and the resolution line.
fn radiance_data_start(bytes: &[u8], start: usize) -> Option<usize> {
    let next_line = |at: usize| -> Option<usize> {
        let nl = bytes.get(at..)?.iter().position(|&b| b == b'\n')?;
        Some(at + nl + 1)
    };
    let mut at = next_line(start)?;
    loop {
        let end = next_line(at)?;
        if end == at + 1 {
            break;
        }
        at = end;
    }
    next_line(at + 1)
}

/// Where each scan line's run-length data starts (after its marker) in Radiance pixel data
/// whose every scanline uses the per-component run-length encoding (the run headers only);
/// `None` when a scanline is encoded another way or the data does not add up (the caller
/// then uses the image crate's decoder). [`decode_rgbe_row`] gives the image crate's values
/// bit for bit.
fn rle_row_starts(data: &[u8], w: u32, h: u32) -> Option<Vec<usize>> {
    let (wu, hu) = (w as usize, h as usize);
    if wu == 0 || hu == 0 {
        return None;
    }
    // Every scan line takes 12 bytes at least (its marker and a run per component): a
    // header's height is not trusted for the allocation.
    let mut starts = Vec::with_capacity(hu.min(data.len() / 12 + 1));
    let mut pos = 0usize;
    for _ in 0..hu {
        let m = data.get(pos..pos + 4)?;
        if !(m[0] == 2 && m[1] == 2 && m[2] < 128) {
            return None;
        }
        starts.push(pos + 4);
        pos += 4;
        for _ in 0..4 {
            pos = skip_rle_component(data, pos, wu)?;
        }
    }
    Some(starts)
}

/// The scale of each RGBE exponent as the image crate's `to_hdr` applies it:
/// `2^(e - 136)` (`2^(e - 128)` per unit of a mantissa byte over 256), `e = 0` black.
const RGBE_SCALE: [f32; 256] = {
    let mut t = [0.0f32; 256];
    let mut e = 1;
    while e < 256 {
        t[e] = f32::from_bits(if e > 1 {
            ((e - 1) as u32) << 23
        } else {
            (e as u32) << 22
        }) * 0.003_906_25;
        e += 1;
    }
    t
};

/// The run-length encoded scan line starting at `at` (checked by [`rle_row_starts`]) into
/// `planes`, which holds its four components (R, G, B, E) one after the other.
fn expand_rgbe_row(data: &[u8], at: usize, planes: &mut [u8]) {
    let wu = planes.len() / 4;
    let mut pos = at;
    for plane in planes.chunks_exact_mut(wu) {
        let mut x = 0usize;
        while x < wu {
            let rl = usize::from(data[pos]);
            pos += 1;
            if rl <= 128 {
                plane[x..x + rl].copy_from_slice(&data[pos..pos + rl]);
                pos += rl;
                x += rl;
            } else {
                let n = rl - 128;
                plane[x..x + n].fill(data[pos]);
                pos += 1;
                x += n;
            }
        }
    }
}

/// The four components of an expanded scan line.
fn rgbe_planes(planes: &[u8]) -> [&[u8]; 4] {
    let wu = planes.len() / 4;
    std::array::from_fn(|i| &planes[i * wu..(i + 1) * wu])
}

/// One run-length encoded scan line starting at `at` (checked by [`rle_row_starts`]) into
/// `row` (RGB), as the image crate's `to_hdr` gives it: `c * 2^(e - 136)`, `e = 0` black.
/// `planes` holds the four components of one line.
fn decode_rgbe_row(data: &[u8], at: usize, planes: &mut [u8], row: &mut [f32]) {
    expand_rgbe_row(data, at, planes);
    let [r, g, b, e] = rgbe_planes(planes);
    for ((((px, &r), &g), &b), &e) in row.chunks_exact_mut(3).zip(r).zip(g).zip(b).zip(e) {
        let scale = RGBE_SCALE[usize::from(e)];
        px[0] = scale * f32::from(r);
        px[1] = scale * f32::from(g);
        px[2] = scale * f32::from(b);
    }
}

/// The luminance ([`crate::luminance`]) of each pixel of the run-length encoded scan line
/// at `at` into `out`, bit for bit that of [`decode_rgbe_row`]'s values, without them: for
/// exponents from [`RGBE_DIRECT_EXPONENT`] on, the weighted sum of the mantissa bytes times
/// the exponent's scale (a power of two, which commutes with every rounding of the sum while
/// the values stay normal); below it, from the decoded values.
fn rgbe_luminance_row(data: &[u8], at: usize, planes: &mut [u8], out: &mut [f32]) {
    expand_rgbe_row(data, at, planes);
    let [r, g, b, e] = rgbe_planes(planes);
    let [wr, wg, wb] = crate::LUMINANCE_WEIGHTS;
    for ((((o, &r), &g), &b), &e) in out.iter_mut().zip(r).zip(g).zip(b).zip(e) {
        let scale = RGBE_SCALE[usize::from(e)];
        let (r, g, b) = (f32::from(r), f32::from(g), f32::from(b));
        *o = if e >= RGBE_DIRECT_EXPONENT {
            (wr * r + wg * g + wb * b) * scale
        } else {
            crate::luminance([scale * r, scale * g, scale * b])
        };
    }
}

/// The smallest exponent whose luminance [`rgbe_luminance_row`] computes from the mantissa
/// bytes: each weighted byte (at least `0.0722`) times `2^(e - 136)` is then a normal
/// `f32` (at least 2^-126), and the largest (`255 * 2^119`) is finite.
const RGBE_DIRECT_EXPONENT: u8 = 14;

/// Reads a PFM file (`PF` colour or `Pf` grey, either byte order, bottom row first).
///
/// # Errors
/// As [`read_hdr_image_with`]; the data length must match the header exactly.
pub fn read_pfm(path: &Path, limits: &Limits) -> Result<Rgb32FImage> {
    let file = File::open(path).map_err(|e| Error::io("cannot read", path, e))?;
    let file_len = file
        .metadata()
        .map_err(|e| Error::io("cannot read", path, e))?
        .len();
    // The header is at most 4 tokens of 64 bytes plus whitespace; the pixel data is then
    // streamed row by row (no whole-file buffer).
    let mut rd = std::io::BufReader::with_capacity(1 << 20, file);
    let bad = |m: &str| Error::invalid("PFM", m, path);
    let mut next_byte = || -> Result<Option<u8>> {
        let mut b = [0u8; 1];
        match rd.read(&mut b) {
            Ok(0) => Ok(None),
            Ok(_) => Ok(Some(b[0])),
            Err(e) => Err(Error::io("cannot read", path, e)),
        }
    };
    // Three whitespace-separated tokens after the magic, then exactly one whitespace byte.
    let mut pos: u64 = 0;
    let mut tokens = Vec::new();
    let mut pending = next_byte()?;
    while tokens.len() < 4 {
        while let Some(b) = pending
            && b.is_ascii_whitespace()
        {
            pos += 1;
            pending = next_byte()?;
        }
        let mut tok = Vec::new();
        while let Some(b) = pending
            && !b.is_ascii_whitespace()
        {
            if tok.len() >= 64 {
                return Err(bad("truncated or malformed header"));
            }
            tok.push(b);
            pos += 1;
            pending = next_byte()?;
        }
        if tok.is_empty() {
            return Err(bad("truncated or malformed header"));
        }
        tokens.push(String::from_utf8_lossy(&tok).into_owned());
    }
    // `pending` is the single whitespace byte after the scale (already consumed).
    pos += 1;
    let channels = match tokens[0].as_str() {
        "PF" => 3,
        "Pf" => 1,
        _ => return Err(bad("magic is not PF or Pf")),
    };
    let w: u64 = tokens[1]
        .parse()
        .map_err(|_| bad("width is not a number"))?;
    let h: u64 = tokens[2]
        .parse()
        .map_err(|_| bad("height is not a number"))?;
    let scale: f32 = tokens[3]
        .parse()
        .map_err(|_| bad("scale is not a number"))?;
    if w == 0 || h == 0 {
        return Err(bad("zero width or height"));
    }
    if !scale.is_finite() || scale == 0.0 {
        return Err(bad("scale must be a non-zero finite number"));
    }
    limits.check(w, h)?;
    let need = w * h * channels * 4;
    let have = file_len.saturating_sub(pos);
    if have < need {
        return Err(bad(&format!(
            "truncated: {have} data bytes, header needs {need}"
        )));
    }
    let little = scale < 0.0;
    let (w, h, ch) = (w as usize, h as usize, channels as usize);
    let mut data = vec![0.0f32; w * h * 3];
    let mut src = vec![0u8; w * ch * 4];
    // Bottom row first in the file.
    for row in data.chunks_exact_mut(w * 3).rev() {
        rd.read_exact(&mut src)
            .map_err(|e| Error::io("cannot read", path, e))?;
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            for (c, v) in px.iter_mut().enumerate() {
                let sc = if ch == 1 { 0 } else { c };
                let o = (x * ch + sc) * 4;
                let b4 = [src[o], src[o + 1], src[o + 2], src[o + 3]];
                *v = if little {
                    f32::from_le_bytes(b4)
                } else {
                    f32::from_be_bytes(b4)
                };
            }
        }
    }
    Rgb32FImage::from_raw(w as u32, h as u32, data).ok_or_else(|| bad("image size overflows"))
}

/// Writes through a closure into a temporary file beside `path`, then renames it; the file
/// gets mode 0666 less the umask, like any file the user creates.
///
/// # Errors
/// [`Error::Io`] if the folder is not writable; the closure's own errors.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    // `.blueshift-<pid>-<random>.partial`, the name `blueshift clean` recognises.
    let prefix = format!(".blueshift-{}-", std::process::id());
    builder.prefix(&prefix).suffix(".partial");
    // 0666 less the umask, as `File::create` would give (tempfile's default is 0600).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder
        .tempfile_in(dir)
        .map_err(|e| Error::io("cannot create a temporary file in", dir, e))?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        write(&mut w)?;
        w.flush().map_err(|e| Error::io("cannot write", path, e))?;
    }
    tmp.persist(path)
        .map_err(|e| Error::io("cannot write", path, e.error))?;
    Ok(())
}

/// Sample precision of an OpenEXR file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExrPrecision {
    /// 16-bit half floats (the usual choice for images).
    #[default]
    Half,
    /// 32-bit floats.
    Float,
}

/// Writes an RGB OpenEXR file (zip-compressed scanlines, written block after block: the same
/// image gives the same bytes every run).
///
/// # Errors
/// [`Error::Io`], or [`Error::EmptyImage`].
pub fn write_exr(path: impl AsRef<Path>, img: &Rgb32FImage, precision: ExrPrecision) -> Result<()> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage, f16};
    let path = path.as_ref();
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::EmptyImage);
    }
    let size = (img.width() as usize, img.height() as usize);
    let px = |pos: Vec2<usize>| -> [f32; 3] {
        let p = img.get_pixel(pos.x() as u32, pos.y() as u32);
        [p[0], p[1], p[2]]
    };
    write_atomic(path, |w| {
        let result = match precision {
            ExrPrecision::Float => {
                let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
                    let [r, g, b] = px(pos);
                    (r, g, b)
                });
                Image::from_channels(size, channels)
                    .write()
                    .non_parallel()
                    .to_buffered(w)
            }
            ExrPrecision::Half => {
                let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
                    let [r, g, b] = px(pos);
                    (f16::from_f32(r), f16::from_f32(g), f16::from_f32(b))
                });
                Image::from_channels(size, channels)
                    .write()
                    .non_parallel()
                    .to_buffered(w)
            }
        };
        result.map_err(|e| match e {
            exr::error::Error::Io(io) => Error::io("cannot write", path, io),
            other => Error::invalid("OpenEXR", other.to_string(), path),
        })
    })
}

/// What the three colour channels of an EXR written by [`write_exr_f32_channels`] hold.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExrSpace {
    /// CIE 1931 XYZ in the R, G, B channels, with the `chromaticities` attribute for XYZ
    /// (red (1, 0), green (0, 1), blue (0, 0), white (1/3, 1/3)), so that colour-managed
    /// readers show the right colours.
    Xyz,
    /// Linear sRGB (Rec. 709 primaries, D65): the OpenEXR default, no attribute written.
    #[default]
    LinearSrgb,
}

/// Writes an OpenEXR of 32-bit float channels atomically: `data` holds `width x height`
/// pixels row by row with `channels` values each (3: RGB, 4: RGBA). The blocks are
/// compressed one after the other, so the same picture always gives the same bytes (a
/// parallel writer emits the blocks in the order they finish).
///
/// # Errors
/// [`Error::Io`]; [`Error::Parameter`] for a size that does not match `data` or a channel
/// count other than 3 or 4.
pub fn write_exr_f32_channels(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    channels: usize,
    data: &[f32],
    space: ExrSpace,
) -> Result<()> {
    use exr::meta::attribute::Chromaticities;
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let path = path.as_ref();
    let size = (width as usize, height as usize);
    if width == 0 || height == 0 || data.len() != size.0 * size.1 * channels {
        return Err(Error::parameter(format!(
            "cannot write {}: {} values for a {width}x{height} image of {channels} channels",
            path.display(),
            data.len()
        )));
    }
    if channels != 3 && channels != 4 {
        return Err(Error::parameter(format!(
            "an EXR of {channels} channels: use 3 or 4"
        )));
    }
    let chromaticities = match space {
        ExrSpace::Xyz => Some(Chromaticities {
            red: Vec2(1.0, 0.0),
            green: Vec2(0.0, 1.0),
            blue: Vec2(0.0, 0.0),
            white: Vec2(1.0 / 3.0, 1.0 / 3.0),
        }),
        ExrSpace::LinearSrgb => None,
    };
    let at = move |p: Vec2<usize>, c: usize| data[(p.y() * size.0 + p.x()) * channels + c];
    write_atomic(path, |w| {
        let result = if channels == 4 {
            let mut img = Image::from_channels(
                size,
                SpecificChannels::rgba(|p: Vec2<usize>| (at(p, 0), at(p, 1), at(p, 2), at(p, 3))),
            );
            img.attributes.chromaticities = chromaticities;
            img.write().non_parallel().to_buffered(w)
        } else {
            let mut img = Image::from_channels(
                size,
                SpecificChannels::rgb(|p: Vec2<usize>| (at(p, 0), at(p, 1), at(p, 2))),
            );
            img.attributes.chromaticities = chromaticities;
            img.write().non_parallel().to_buffered(w)
        };
        result.map_err(|e| match e {
            exr::error::Error::Io(io) => Error::io("cannot write", path, io),
            other => Error::invalid("OpenEXR", other.to_string(), path),
        })
    })
}

/// Writes a Radiance RGBE `.hdr` file (negative and non-finite values become 0).
///
/// # Errors
/// [`Error::Io`], or [`Error::EmptyImage`].
pub fn write_radiance_hdr(path: impl AsRef<Path>, img: &Rgb32FImage) -> Result<()> {
    let path = path.as_ref();
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::EmptyImage);
    }
    let pixels: Vec<image::Rgb<f32>> = img
        .pixels()
        .map(|p| image::Rgb(p.0.map(|v| if v.is_finite() && v > 0.0 { v } else { 0.0 })))
        .collect();
    write_atomic(path, |w| {
        image::codecs::hdr::HdrEncoder::new(w)
            .encode(&pixels, img.width() as usize, img.height() as usize)
            .map_err(|e| Error::invalid("Radiance HDR", e.to_string(), path))
    })
}

/// Writes a colour PFM file (little-endian, bottom row first, as the format requires).
///
/// # Errors
/// [`Error::Io`], or [`Error::EmptyImage`].
pub fn write_pfm(path: impl AsRef<Path>, img: &Rgb32FImage) -> Result<()> {
    let path = path.as_ref();
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::EmptyImage);
    }
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = img.as_raw();
    let header = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    // Streamed row by row (bottom row first in the file): no whole-image byte buffer.
    write_atomic(path, |wr| {
        let mut row_bytes = vec![0u8; w * 12];
        wr.write_all(&header)
            .map_err(|e| Error::io("cannot write", path, e))?;
        for y in (0..h).rev() {
            for (o, v) in row_bytes
                .chunks_exact_mut(4)
                .zip(&raw[y * w * 3..(y + 1) * w * 3])
            {
                o.copy_from_slice(&v.to_le_bytes());
            }
            wr.write_all(&row_bytes)
                .map_err(|e| Error::io("cannot write", path, e))?;
        }
        Ok(())
    })
}

/// Bits per channel of a PNG.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PngDepth {
    /// 8 bits per channel.
    #[default]
    Eight,
    /// 16 bits per channel.
    Sixteen,
}

/// The sRGB transfer function (IEC 61966-2-1) of a display-linear value in [0, 1]; beyond
/// it clipped (+Inf is white, -Inf black), NaN black.
#[must_use]
pub fn srgb_encode(v: f32) -> f32 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`srgb_encode`].
#[must_use]
pub fn srgb_decode(v: f32) -> f32 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The 8-bit sRGB code of a display-linear value: `round(255 srgb_encode(v))` (values
/// clamped to [0, 1], +inf as 255, NaN and -inf as 0), bit for bit, without `powf`: the code is
/// the number of the 255 thresholds (the smallest `f32` reaching each code, found once by
/// bisection over `f32` bit patterns of [`srgb_encode`] itself) at or below `v`. A table
/// indexed by the top bits of `v` (one entry per 2^15 bit patterns, a 1/256 step in
/// relative value, where the codes advance by less than one) gives the code at the entry's
/// start, and one comparison with the next threshold finishes it.
#[must_use]
#[inline]
pub fn srgb8(v: f32) -> u8 {
    srgb8_with(srgb8_tables(), v)
}

/// [`srgb8`] of every value of `values` into `out` (the same length): eight values at a
/// time with AVX2 gathers where the CPU has them, the same codes.
pub(crate) fn srgb8_row(values: &[f32], out: &mut [u8]) {
    let t = srgb8_tables();
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 detected just above.
        #[allow(unsafe_code)]
        unsafe {
            done = srgb8_lanes_avx2(t, values, out);
        }
    }
    for (o, &v) in out[done..].iter_mut().zip(&values[done..]) {
        *o = srgb8_with(t, v);
    }
}

/// [`srgb8_with`] of the leading multiple of 8 values of `values` (and `out`): the same
/// steps in eight lanes, the entry from [`Srgb8Tables::lanes`] (clamped at its first
/// entry, whose code is 0 as below it) and the threshold by gathers. Returns how many values
/// it did.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
fn srgb8_lanes_avx2(t: &Srgb8Tables, values: &[f32], out: &mut [u8]) -> usize {
    use std::arch::x86_64::{
        _CMP_GE_OQ, _CMP_GT_OQ, _mm_cvtsi128_si64, _mm_unpacklo_epi32, _mm256_and_ps,
        _mm256_castps_si256, _mm256_castsi256_si128, _mm256_cmp_ps, _mm256_extracti128_si256,
        _mm256_i32gather_epi32, _mm256_i32gather_ps, _mm256_loadu_ps, _mm256_max_epi32,
        _mm256_min_epi32, _mm256_min_ps, _mm256_packus_epi16, _mm256_packus_epi32,
        _mm256_set1_epi32, _mm256_set1_ps, _mm256_setzero_ps, _mm256_setzero_si256,
        _mm256_srli_epi32, _mm256_sub_epi32,
    };
    let n = values.len().min(out.len()) / 8 * 8;
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let first = _mm256_set1_epi32(t.lanes_first as i32);
    let last = _mm256_set1_epi32(t.lanes.len() as i32 - 1);
    for (v, o) in values[..n]
        .as_chunks::<8>()
        .0
        .iter()
        .zip(out[..n].as_chunks_mut::<8>().0)
    {
        // SAFETY: `v` is 8 floats; every gathered index lies in its table (the entry index
        // is clamped to `lanes`, the codes it holds are below 256, `thresholds`' length).
        let codes = unsafe {
            let v = _mm256_loadu_ps(v.as_ptr());
            // Positive (ordered: NaN fails) values, +inf included, clipped to 1.
            let ok = _mm256_cmp_ps::<_CMP_GT_OQ>(v, zero);
            let x = _mm256_and_ps(_mm256_min_ps(v, one), ok);
            let bits = _mm256_srli_epi32::<{ SRGB8_SHIFT as i32 }>(_mm256_castps_si256(x));
            let entry = _mm256_min_epi32(
                _mm256_max_epi32(_mm256_sub_epi32(bits, first), _mm256_setzero_si256()),
                last,
            );
            let code = _mm256_i32gather_epi32::<4>(t.lanes.as_ptr().cast(), entry);
            let th = _mm256_i32gather_ps::<4>(t.thresholds.as_ptr(), code);
            // All ones (-1) where `x` reaches the next code's threshold.
            let up = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(x, th));
            let code = _mm256_sub_epi32(code, up);
            // Eight 32-bit codes to bytes: each 128-bit half packs its four into its low
            // four bytes.
            let bytes = _mm256_packus_epi16(
                _mm256_packus_epi32(code, code),
                _mm256_packus_epi32(code, code),
            );
            _mm_cvtsi128_si64(_mm_unpacklo_epi32(
                _mm256_castsi256_si128(bytes),
                _mm256_extracti128_si256::<1>(bytes),
            ))
        };
        *o = codes.to_le_bytes();
    }
    n
}

#[inline]
fn srgb8_with(t: &Srgb8Tables, v: f32) -> u8 {
    // Branch-free: NaN and negatives to 0, values from 1 on (+inf too) to 1 (code 255:
    // 1.0's entry starts at 255 and `thresholds[255]` is infinite).
    let x = if v > 0.0 { v.min(1.0) } else { 0.0 };
    let i = ((x.to_bits() >> SRGB8_SHIFT) as usize).min(t.start.len() - 1);
    let code = t.start[i];
    code + u8::from(x >= t.thresholds[code as usize])
}

/// `f32` bit patterns per entry of [`Srgb8Tables::start`].
const SRGB8_SHIFT: u32 = 15;

struct Srgb8Tables {
    /// `thresholds[k]`: the smallest `v` in (0, 1] whose code is above `k`; infinite at 255.
    thresholds: [f32; 256],
    /// The code of the first `f32` of each run of 2^15 bit patterns below 1.0.
    start: Vec<u8>,
    /// `start` from entry `lanes_first` on as 32-bit values (for gathers): the entry of
    /// the first threshold, every value below whose code is 0.
    lanes: Vec<u32>,
    lanes_first: u32,
}

fn srgb8_reference(v: f32) -> u8 {
    (srgb_encode(v) * 255.0).round() as u8
}

fn srgb8_tables() -> &'static Srgb8Tables {
    static T: std::sync::OnceLock<Srgb8Tables> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        let mut thresholds = [f32::INFINITY; 256];
        for (k, th) in thresholds.iter_mut().take(255).enumerate() {
            // Smallest bit pattern in [0, 1.0] whose code exceeds k (codes rise with v).
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if srgb8_reference(f32::from_bits(mid)) as usize > k {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            *th = f32::from_bits(lo);
        }
        let entries = (1.0f32.to_bits() >> SRGB8_SHIFT) as usize + 1;
        // The number of thresholds at or below each entry's first value (they rise, as
        // the entries do: one walk along both).
        let mut code = 0usize;
        let start = (0..entries)
            .map(|i| {
                let v = f32::from_bits((i as u32) << SRGB8_SHIFT);
                while code < 255 && thresholds[code] <= v {
                    code += 1;
                }
                code as u8
            })
            .collect::<Vec<u8>>();
        let lanes_first = thresholds[0].to_bits() >> SRGB8_SHIFT;
        let lanes = start[lanes_first as usize..]
            .iter()
            .map(|&c| u32::from(c))
            .collect();
        Srgb8Tables {
            thresholds,
            start,
            lanes,
            lanes_first,
        }
    })
}

/// The display image's sRGB codes, 8 bits per channel, row-major RGB (rows in parallel;
/// the same bytes on any thread count).
#[must_use]
pub fn display_to_srgb8(display: &Rgb32FImage) -> Vec<u8> {
    use rayon::prelude::*;
    let mut out = vec![0u8; display.as_raw().len()];
    let row = 3 * display.width().max(1) as usize;
    out.par_chunks_mut(row)
        .zip(display.as_raw().par_chunks(row))
        .for_each(|(o, i)| srgb8_row(i, o));
    out
}

/// The PNG header settings every blueshift PNG is written with: the Up filter on every row
/// (adaptive filtering, `image`'s default, tries all five filters per row and took twice
/// the time of the compression for files 3 % smaller: `benches/io.rs`, group `png_8mp`, on
/// an 8-megapixel tone-mapped image). [`encode_png`] compresses the filtered rows itself,
/// in parallel ([`crate::zlib`]), and writes them as IDAT chunks.
pub fn png_encoder<W: Write>(w: W, width: u32, height: u32) -> png::Encoder<'static, W> {
    let mut enc = png::Encoder::new(w, width, height);
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(PNG_FILTER);
    enc
}

/// The row filter of [`png_encoder`].
pub const PNG_FILTER: png::Filter = png::Filter::Up;

/// Encodes 8- or 16-bit RGB or RGBA samples (16-bit ones big-endian, as PNG stores them)
/// as a PNG into `w` with [`png_encoder`].
///
/// # Errors
/// [`Error::Parameter`] for a sample count that does not match the size; the writer's
/// errors as [`Error::Invalid`] ("PNG").
pub fn encode_png<W: Write>(
    w: W,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
) -> Result<()> {
    let channels = match color {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Indexed => {
            return Err(Error::parameter("PNG: indexed colour is not written"));
        }
    };
    let bytes = match depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        other => {
            return Err(Error::parameter(format!(
                "PNG: {other:?} bit samples are not written (8 or 16)"
            )));
        }
    };
    if data.len() as u64 != u64::from(width) * u64::from(height) * channels * bytes {
        return Err(Error::parameter(format!(
            "PNG: {} bytes for a {width}x{height} image",
            data.len()
        )));
    }
    let row_bytes = (u64::from(width) * channels * bytes) as usize;
    // The pixel data compressed in parallel ([`crate::zlib`]).
    let parts = crate::zlib::png_zlib_parts(data, row_bytes, height as usize);
    write_png_parts(w, width, height, color, depth, &parts)
}

/// A PNG of the zlib stream `parts` ([`crate::zlib`]), one IDAT chunk each.
fn write_png_parts<W: Write>(
    w: W,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    parts: &[Vec<u8>],
) -> Result<()> {
    let mut enc = png_encoder(w, width, height);
    enc.set_color(color);
    enc.set_depth(depth);
    let err = |e: png::EncodingError| Error::invalid("PNG", e.to_string(), Path::new("<png>"));
    let mut wr = enc.write_header().map_err(err)?;
    for part in parts {
        wr.write_chunk(png::chunk::IDAT, part).map_err(err)?;
    }
    wr.finish().map_err(err)
}

/// Writes an 8-bit RGB PNG whose rows (`3 * width` sRGB codes each) `rows` makes while the
/// file's stream is compressed ([`crate::zlib::png_zlib_parts_of`]): the same bytes as
/// [`write_rgb8_png`] of the image of those rows, without the image.
///
/// # Errors
/// [`Error::EmptyImage`], [`Error::Io`]; the encoder's errors as [`Error::Invalid`].
pub fn write_rgb8_png_rows(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    rows: &impl crate::zlib::PngRows,
) -> Result<()> {
    let path = path.as_ref();
    if width == 0 || height == 0 {
        return Err(Error::EmptyImage);
    }
    let parts = crate::zlib::png_zlib_parts_of(rows, 3 * width as usize, height as usize);
    write_atomic(path, |wr| {
        let (color, depth) = (png::ColorType::Rgb, png::BitDepth::Eight);
        write_png_parts(wr, width, height, color, depth, &parts).map_err(png_error_in(path))
    })
}

/// Encodes a display-linear image as an sRGB PNG of 8 or 16 bits per channel (values
/// clamped to [0, 1], NaN as 0).
///
/// # Errors
/// [`Error::Io`], or [`Error::EmptyImage`].
pub fn write_png(path: impl AsRef<Path>, display: &Rgb32FImage, depth: PngDepth) -> Result<()> {
    let path = path.as_ref();
    if display.width() == 0 || display.height() == 0 {
        return Err(Error::EmptyImage);
    }
    let (w, h) = display.dimensions();
    match depth {
        PngDepth::Eight => {
            write_png_samples(path, w, h, png::BitDepth::Eight, &display_to_srgb8(display))
        }
        PngDepth::Sixteen => {
            use rayon::prelude::*;
            let bytes: Vec<u8> = display
                .as_raw()
                .par_iter()
                .flat_map_iter(|&v| ((srgb_encode(v) * 65535.0).round() as u16).to_be_bytes())
                .collect();
            write_png_samples(path, w, h, png::BitDepth::Sixteen, &bytes)
        }
    }
}

/// Encodes an 8-bit RGB image as PNG straight into `path` (no temporary file: for callers
/// that stage their own, such as the CLI's output sets) with [`png_encoder`]'s settings.
///
/// # Errors
/// [`Error::Io`]; the encoder's errors as [`Error::Invalid`].
pub fn save_rgb8_png(path: &Path, img: &RgbImage) -> Result<()> {
    let file = File::create(path).map_err(|e| Error::io("cannot write", path, e))?;
    let mut w = BufWriter::new(file);
    let (width, height) = img.dimensions();
    encode_png(
        &mut w,
        width,
        height,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        img.as_raw(),
    )
    .map_err(|e| match e {
        Error::Invalid { message, .. } => Error::invalid("PNG", message, path),
        e => e,
    })?;
    w.flush().map_err(|e| Error::io("cannot write", path, e))
}

/// Writes an 8-bit RGB image (e.g. a pseudocolour picture) as PNG.
///
/// # Errors
/// [`Error::Io`].
pub fn write_rgb8_png(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    let (w, h) = img.dimensions();
    write_png_samples(path.as_ref(), w, h, png::BitDepth::Eight, img.as_raw())
}

fn write_png_samples(path: &Path, w: u32, h: u32, depth: png::BitDepth, data: &[u8]) -> Result<()> {
    write_atomic(path, |wr| {
        encode_png(wr, w, h, png::ColorType::Rgb, depth, data).map_err(png_error_in(path))
    })
}

/// The PNG writer's errors naming the file written (they name none).
fn png_error_in(path: &Path) -> impl Fn(Error) -> Error + '_ {
    move |e| match e {
        Error::Invalid { message, .. } => Error::invalid("PNG", message, path),
        e => e,
    }
}

/// Writes a numbered OpenEXR sequence (`<prefix>0000.exr`, `<prefix>0001.exr`, ...): the
/// HDR video output of HDR VolVis, readable by HDR movie players and `pfsin`.
#[derive(Debug)]
pub struct ExrSequenceWriter {
    dir: PathBuf,
    prefix: String,
    next: usize,
    precision: ExrPrecision,
}

impl ExrSequenceWriter {
    /// A writer into `dir` (created if missing) with file names `<prefix>NNNN.exr`.
    ///
    /// # Errors
    /// [`Error::Io`] if the folder cannot be created; [`Error::Parameter`] if the prefix
    /// contains a path separator.
    pub fn new(dir: impl Into<PathBuf>, prefix: &str, precision: ExrPrecision) -> Result<Self> {
        let dir = dir.into();
        if prefix.contains(['/', '\\']) {
            return Err(Error::parameter(format!(
                "sequence prefix must be a file name, got {prefix:?}"
            )));
        }
        std::fs::create_dir_all(&dir).map_err(|e| Error::io("cannot create folder", &dir, e))?;
        Ok(Self {
            dir,
            prefix: prefix.to_owned(),
            next: 0,
            precision,
        })
    }

    /// The path frame `index` is written to.
    #[must_use]
    pub fn frame_path(&self, index: usize) -> PathBuf {
        self.dir.join(format!("{}{index:04}.exr", self.prefix))
    }

    /// Writes the next frame and returns its path.
    ///
    /// # Errors
    /// As [`write_exr`].
    pub fn push(&mut self, frame: &Rgb32FImage) -> Result<PathBuf> {
        let path = self.frame_path(self.next);
        write_exr(&path, frame, self.precision)?;
        self.next += 1;
        Ok(path)
    }

    /// Number of frames written.
    #[must_use]
    pub fn len(&self) -> usize {
        self.next
    }

    /// Whether no frame has been written.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.next == 0
    }
}

/// The frames of a numbered sequence in `dir` (`<prefix><digits>.exr`), sorted by number.
///
/// # Errors
/// [`Error::Io`] if the folder cannot be listed.
pub fn list_exr_sequence(dir: impl AsRef<Path>, prefix: &str) -> Result<Vec<PathBuf>> {
    let dir = dir.as_ref();
    let mut frames: Vec<(u64, PathBuf)> = std::fs::read_dir(dir)
        .map_err(|e| Error::io("cannot list", dir, e))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let digits = name.strip_prefix(prefix)?.strip_suffix(".exr")?;
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            Some((digits.parse().ok()?, e.path()))
        })
        .collect();
    frames.sort();
    Ok(frames.into_iter().map(|(_, p)| p).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every half-float bit pattern converts as the `half` crate converts it (NaN to NaN),
    /// at two offsets, in rows whose lengths are not multiples of eight.
    #[test]
    fn halves_convert_as_the_half_crate_does() {
        let all: Vec<u16> = (0..=u16::MAX).collect();
        for skip in [0, 3] {
            let src: Vec<u8> = all[skip..].iter().flat_map(|h| h.to_ne_bytes()).collect();
            let mut out = vec![0.0f32; all.len() - skip];
            halves_to_f32(&src, &mut out);
            for (&h, &f) in all[skip..].iter().zip(&out) {
                assert_is_half(f, h);
            }
        }
    }

    /// `got` is the `half` crate's f32 of the half bit pattern `h` (NaN for NaN).
    fn assert_is_half(got: f32, h: u16) {
        let want = half::f16::from_bits(h).to_f32();
        if want.is_nan() {
            assert!(got.is_nan(), "{h:#06x}");
        } else {
            assert_eq!(got.to_bits(), want.to_bits(), "{h:#06x}");
        }
    }

    /// Three channels of halves interleave as each converts alone, in rows of every length
    /// up to 40 pixels (random bit patterns; NaN to NaN).
    #[test]
    fn half_channels_interleave_as_each_converts() {
        let mut rng = crate::xorshift(0x1234_5678_9abc_def1);
        let mut next = || rng() as u16;
        for n in 0..=40usize {
            let chans: Vec<Vec<u8>> = (0..3)
                .map(|_| (0..n).flat_map(|_| next().to_ne_bytes()).collect())
                .collect();
            let mut out = vec![0.0f32; 3 * n];
            halves_to_rgb(&chans[0], &chans[1], &chans[2], &mut out);
            for (i, o) in out.iter().enumerate() {
                let c = &chans[i % 3];
                assert_is_half(*o, u16::from_ne_bytes([c[2 * (i / 3)], c[2 * (i / 3) + 1]]));
            }
        }
    }

    /// A row's codes (eight lanes at a time where the CPU has AVX2) are [`srgb8`]'s, one
    /// value at a time (itself the formula's, `tests/io.rs`): on every 7th `f32` bit
    /// pattern in [0, 1] (each code's edges among them), both sides of every threshold, and
    /// the special values, in rows whose lengths are not multiples of eight.
    #[test]
    fn srgb8_rows_equal_srgb8() {
        let t = srgb8_tables();
        let mut values: Vec<f32> = (0..=1.0f32.to_bits())
            .step_by(7)
            .map(f32::from_bits)
            .collect();
        for th in &t.thresholds[..255] {
            let b = th.to_bits();
            values.extend([b - 1, b, b + 1].map(f32::from_bits));
        }
        values.extend([
            -1.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-45,
            1.5,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
        ]);
        for len in [values.len(), 13, 7, 0] {
            let v = &values[values.len() - len..];
            let mut got = vec![0u8; len];
            srgb8_row(v, &mut got);
            for (g, &x) in got.iter().zip(v) {
                assert_eq!(*g, srgb8(x), "v = {x:e}");
            }
        }
        // Clipped: +inf is white and -inf black, as the formula clips; NaN is black.
        let mut row = [0u8; 16];
        let special = [f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 2.0].repeat(4);
        srgb8_row(&special, &mut row);
        assert_eq!(row[..4], [255, 0, 0, 255]);
        assert_eq!(row[12..], [255, 0, 0, 255]);
        assert_eq!(srgb8(f32::INFINITY), 255);
        assert_eq!((srgb_encode(f32::INFINITY) * 255.0).round() as u8, 255);
    }

    /// The image the block reader's bands hold, decoded row by row (the tone-mapping
    /// passes) and whole (the image readers), which must agree.
    fn blocks_image(path: &Path) -> Rgb32FImage {
        let image = blocks_image_by(path, false);
        let by_offsets = blocks_image_by(path, true);
        assert_eq!(image.dimensions(), by_offsets.dimensions());
        assert_same_bits(&image, &by_offsets, "file order and offsets", path);
        image
    }

    /// `a` and `b` hold the same values, bit for bit.
    fn assert_same_bits(a: &[f32], b: &[f32], what: &str, path: &Path) {
        assert_eq!(a.len(), b.len(), "{what}: {}", path.display());
        let same = a.iter().zip(b).all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "{what} differ: {}", path.display());
    }

    thread_local! {
        /// Reads that [`read_blocks_at_offsets`] completed on this thread.
        pub(super) static READ_AT_OFFSETS: std::cell::Cell<usize> =
            const { std::cell::Cell::new(0) };
    }

    /// [`blocks_image`] with the blocks read in file order or at their offsets.
    fn blocks_image_by(path: &Path, at_offsets: bool) -> Rgb32FImage {
        let Some(ExrRead::Bands(bands)) = read_exr_blocks_by(path, true, at_offsets).unwrap()
        else {
            panic!("read by blocks");
        };
        let Some(ExrRead::Image(direct)) = read_exr_blocks_by(path, false, at_offsets).unwrap()
        else {
            panic!("read by blocks");
        };
        let source = HdrSource::from_bands(bands);
        let (w, h) = source.dimensions();
        let mut by_rows = vec![0.0f32; 3 * (w * h) as usize];
        let mut scratch = RowScratch::default();
        for (y, row) in by_rows.chunks_exact_mut(3 * w as usize).enumerate() {
            source.decode_row(y, &mut scratch, row);
        }
        let whole = source.into_image();
        assert_same_bits(&whole, &by_rows, "rows and image", path);
        assert_same_bits(&whole, &direct, "bands and direct", path);
        whole
    }

    /// Writes an OpenEXR file with the exr crate: channels `names` of type `ty`, filled from
    /// a pattern with every kind of value (negative, zero, tiny, huge), in `encoding`.
    fn exr_file(
        path: &Path,
        size: (usize, usize),
        names: &[&str],
        ty: exr::meta::attribute::SampleType,
        encoding: exr::prelude::Encoding,
        position: (i32, i32),
    ) {
        use exr::meta::attribute::SampleType;
        use exr::prelude::*;
        let n = size.0 * size.1;
        let channels: Vec<AnyChannel<FlatSamples>> = names
            .iter()
            .enumerate()
            .map(|(c, name)| {
                let v = |i: usize| {
                    let t = (i * 7 + c * 13) % 23;
                    match t {
                        0 => 0.0,
                        1 => -2.5,
                        2 => 6.0e4,
                        3 => 1.0e-6,
                        _ => (t as f32 * 0.37 + i as f32 * 1.0e-3).exp2() - 1.0,
                    }
                };
                let samples = match ty {
                    SampleType::F16 => {
                        FlatSamples::F16((0..n).map(|i| f16::from_f32(v(i))).collect())
                    }
                    SampleType::F32 => FlatSamples::F32((0..n).map(v).collect()),
                    SampleType::U32 => {
                        FlatSamples::U32((0..n).map(|i| v(i).abs() as u32).collect())
                    }
                };
                AnyChannel::new(*name, samples)
            })
            .collect();
        let attributes = LayerAttributes {
            layer_position: Vec2(position.0, position.1),
            ..LayerAttributes::default()
        };
        let layer = Layer::new(
            size,
            attributes,
            encoding,
            AnyChannels::sort(channels.into()),
        );
        Image::from_layer(layer).write().to_file(path).unwrap();
    }

    /// What the exr crate's own image reader gives for the file, interleaved as R, G, B
    /// (or Y three times).
    fn exr_crate_reference(path: &Path) -> (u32, u32, Vec<f32>) {
        use exr::prelude::*;
        let image = read_all_flat_layers_from_file(path).unwrap();
        let layer = &image.layer_data[0];
        let find = |name: &str| {
            layer
                .channel_data
                .list
                .iter()
                .find(|c| c.name.to_string().rsplit('.').next() == Some(name))
        };
        let picked = match (find("R"), find("G"), find("B")) {
            (Some(r), Some(g), Some(b)) => [r, g, b],
            _ => [find("Y").unwrap(); 3],
        };
        let values: Vec<Vec<f32>> = picked
            .iter()
            .map(|c| c.sample_data.values_as_f32().collect())
            .collect();
        let n = values[0].len();
        let data = (0..3 * n).map(|i| values[i % 3][i / 3]).collect();
        (layer.size.width() as u32, layer.size.height() as u32, data)
    }

    /// The block reader gives the exr crate's own reader's values bit for bit, for every
    /// compression the crate writes, half, float and uint samples, RGB, RGBA, Y alone and
    /// layer-prefixed channels beside others, decreasing line order, a displaced data window,
    /// and sizes whose last block is short; tiled and multi-layer files are left to the
    /// crate's reader (and still read the same).
    #[test]
    fn exr_blocks_equal_the_exr_crates_reader() {
        use exr::meta::attribute::{LineOrder, SampleType};
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        let compressions = [
            Compression::Uncompressed,
            Compression::RLE,
            Compression::ZIP1,
            Compression::ZIP16,
            Compression::PIZ,
            Compression::PXR24,
            Compression::B44,
            Compression::B44A,
        ];
        let channel_sets: [&[&str]; 4] = [
            &["R", "G", "B"],
            &["A", "B", "G", "R"],
            &["Y"],
            &["Z", "diffuse.B", "diffuse.G", "diffuse.R"],
        ];
        let mut read_by_blocks = 0;
        let at_offsets = READ_AT_OFFSETS.get();
        for (i, &compression) in compressions.iter().enumerate() {
            for (j, ty) in [SampleType::F16, SampleType::F32, SampleType::U32]
                .into_iter()
                .enumerate()
            {
                for (k, size) in [(1, 1), (37, 53), (300, 40)].into_iter().enumerate() {
                    let names = channel_sets[(i + j + k) % channel_sets.len()];
                    let line_order = if (i + k) % 2 == 0 {
                        LineOrder::Increasing
                    } else {
                        LineOrder::Decreasing
                    };
                    let blocks = [
                        Blocks::ScanLines,
                        Blocks::Tiles(Vec2(16, 16)),
                        Blocks::Tiles(Vec2(64, 8)),
                    ][(i + 2 * j + k) % 3];
                    let encoding = Encoding {
                        compression,
                        blocks,
                        line_order,
                    };
                    let position = if k == 1 { (-5, 17) } else { (0, 0) };
                    exr_file(&path, size, names, ty, encoding, position);
                    let (w, h, want) = exr_crate_reference(&path);
                    let got = blocks_image(&path);
                    read_by_blocks += 1;
                    assert_eq!((got.width(), got.height()), (w, h));
                    let what = format!(
                        "{compression:?} {ty:?} {size:?} {names:?} {line_order:?} {blocks:?}"
                    );
                    for (a, b) in got.as_raw().iter().zip(&want) {
                        assert_eq!(a.to_bits(), b.to_bits(), "{what}");
                    }
                    assert_eq!(
                        read_hdr_image(&path).unwrap().as_raw(),
                        got.as_raw(),
                        "{what}"
                    );
                }
            }
        }
        assert_eq!(read_by_blocks, 72);
        // Every file was read at its offsets too (compact and whole by `blocks_image`, whole
        // by `read_hdr_image`).
        assert_eq!(READ_AT_OFFSETS.get() - at_offsets, 3 * 72);
        // A mip-mapped tiled file: its full-resolution level (the smaller ones are skipped).
        let (w, h) = (45, 30);
        let level = |l: usize| {
            let (lw, lh) = ((w >> l).max(1), (h >> l).max(1));
            FlatSamples::F16(
                (0..lw * lh)
                    .map(|i| f16::from_f32((i * (l + 1)) as f32 * 0.25))
                    .collect(),
            )
        };
        use exr::math::RoundingMode;
        let levels = exr::meta::compute_level_count(RoundingMode::Down, w.max(h));
        let channels: Vec<AnyChannel<Levels<FlatSamples>>> = ["B", "G", "R"]
            .iter()
            .map(|n| {
                let level_data = (0..levels).map(level).collect();
                AnyChannel::new(
                    *n,
                    Levels::Mip {
                        rounding_mode: RoundingMode::Down,
                        level_data,
                    },
                )
            })
            .collect();
        let encoding = Encoding {
            compression: Compression::ZIP16,
            blocks: Blocks::Tiles(Vec2(16, 16)),
            line_order: LineOrder::Increasing,
        };
        let layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            encoding,
            AnyChannels::sort(channels.into()),
        );
        Image::from_layer(layer).write().to_file(&path).unwrap();
        let before = READ_AT_OFFSETS.get();
        let got = blocks_image(&path);
        assert_eq!(
            READ_AT_OFFSETS.get() - before,
            2,
            "mip levels read at offsets"
        );
        let FlatSamples::F16(full) = level(0) else {
            unreachable!()
        };
        for (i, p) in got.as_raw().chunks_exact(3).enumerate() {
            assert_eq!(p, [full[i].to_f32(); 3], "pixel {i}");
        }
    }

    /// PIZ blocks of float samples whose low halves are noise: Huffman codes of 13 to 24
    /// bits, alone or among short ones (the decoder's unchecked loop takes both), read as
    /// the exr crate reads them.
    #[test]
    fn piz_blocks_of_long_codes_read_as_the_exr_crate_reads_them() {
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        // Blocks of 32 lines of 1024 pixels: large enough that the Huffman table (up to
        // 65,536 codes) is a small part of the block, which PIZ then compresses.
        let (w, h) = (1024, 40);
        let mut next = crate::xorshift(0x2545_f491_4f6c_dd1d);
        for noisy in [1u64, 3, 20] {
            // One sample in `noisy` any float from 1 to 2, the others one of eight.
            let mut channel = |name: &str| {
                let v = (0..w * h)
                    .map(|_| {
                        let r = next();
                        if r.is_multiple_of(noisy) {
                            f32::from_bits(0x3f80_0000 + (r >> 8) as u32 % 0x0080_0000)
                        } else {
                            (r >> 40) as f32 % 8.0 * 0.5
                        }
                    })
                    .collect();
                AnyChannel::new(name, FlatSamples::F32(v))
            };
            let channels: Vec<_> = ["B", "G", "R"].iter().map(|n| channel(n)).collect();
            let layer = Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding {
                    compression: Compression::PIZ,
                    blocks: Blocks::ScanLines,
                    line_order: exr::meta::attribute::LineOrder::Increasing,
                },
                AnyChannels::sort(channels.into()),
            );
            Image::from_layer(layer).write().to_file(&path).unwrap();
            let len = std::fs::metadata(&path).unwrap().len() as usize;
            assert!(len < w * h * 12, "PIZ compressed the samples ({noisy})");
            let (_, _, want) = exr_crate_reference(&path);
            let got = blocks_image(&path);
            assert_same_bits(&got, &want, &format!("one in {noisy}"), &path);
        }
    }

    /// The first tone-mapping pass's statistics computed as the bands are decoded
    /// ([`ExrBands::row_stats`]) give what the pass gives over the decoded rows: the
    /// cleaning's report, the luminance range and the log-average, for scan lines and
    /// tiles, PIZ, ZIP and uncompressed blocks, half, float and uint samples, RGB, RGBA and
    /// Y, dirty values (negative) and clean ones (uint).
    #[test]
    fn row_statistics_of_the_read_equal_the_first_pass() {
        use exr::meta::attribute::{LineOrder, SampleType};
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        let (mut dirty, mut lit) = (0, 0);
        for compression in [
            Compression::PIZ,
            Compression::ZIP16,
            Compression::Uncompressed,
        ] {
            for blocks in [Blocks::ScanLines, Blocks::Tiles(Vec2(16, 8))] {
                for ty in [SampleType::F16, SampleType::F32, SampleType::U32] {
                    for names in [&["R", "G", "B"][..], &["A", "B", "G", "R"], &["Y"]] {
                        let what = format!("{compression:?} {blocks:?} {ty:?} {names:?}");
                        let encoding = Encoding {
                            compression,
                            blocks,
                            line_order: LineOrder::Increasing,
                        };
                        exr_file(&path, (45, 37), names, ty, encoding, (0, 0));
                        let Some(ExrRead::Bands(mut bands)) =
                            read_exr_blocks_by(&path, true, true).unwrap()
                        else {
                            panic!("read by blocks: {what}");
                        };
                        let pre = std::mem::take(&mut bands.row_stats);
                        assert_eq!(pre.len(), 37, "{what}");
                        let mut src = HdrSource::from_bands(bands);
                        let want =
                            [false, true].map(|log| crate::rows::clean_stats(&src, None, log));
                        if let Source::Exr(b) = &mut src.inner {
                            b.row_stats = pre;
                        }
                        assert!(src.row_stats().is_some(), "{what}");
                        let got =
                            [false, true].map(|log| crate::rows::clean_stats(&src, None, log));
                        assert_eq!(got, want, "{what}");
                        let (stats, lavg) = got[1].unwrap();
                        dirty += usize::from(stats.report.total() > 0);
                        lit += usize::from(lavg.is_some());
                    }
                }
            }
        }
        // Both kinds of rows were met, and the log-averages were defined.
        assert!(dirty > 10 && dirty < 54, "{dirty} dirty files of 54");
        assert_eq!(lit, 54);
    }

    /// Files whose offset table does not say where each block is (entries swapped, an entry
    /// past the end) are read in file order, as the exr crate reads them; a header with
    /// long attributes is found whole (its table read where the file's first block's offset
    /// says it ends).
    #[test]
    fn irregular_offset_tables_are_read_in_file_order() {
        use exr::meta::attribute::{LineOrder, SampleType, Text};
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        for (compression, blocks) in [
            (Compression::Uncompressed, Blocks::ScanLines),
            (Compression::ZIP16, Blocks::ScanLines),
            (Compression::PIZ, Blocks::Tiles(Vec2(16, 8))),
        ] {
            let encoding = Encoding {
                compression,
                blocks,
                line_order: LineOrder::Increasing,
            };
            exr_file(
                &path,
                (40, 50),
                &["R", "G", "B"],
                SampleType::F16,
                encoding,
                (0, 0),
            );
            let (_, _, want) = exr_crate_reference(&path);
            let bytes = std::fs::read(&path).unwrap();
            let meta = exr::meta::MetaData::read_from_file(&path, false).unwrap();
            let count = meta.headers[0].chunk_count;
            let table = exr_header_end(
                &File::open(&path).unwrap(),
                bytes.len() as u64,
                matches!(blocks, Blocks::Tiles(_)),
            )
            .unwrap() as usize;
            let offset = |i: usize| {
                u64::from_le_bytes(bytes[table + 8 * i..table + 8 * i + 8].try_into().unwrap())
            };
            // The blocks follow the table, the first one straight after it.
            assert_eq!(
                (0..count).map(offset).min(),
                Some((table + 8 * count) as u64)
            );
            let swapped = {
                let mut b = bytes.clone();
                b.copy_within(table..table + 8, table + 8);
                b[table..table + 8].copy_from_slice(&bytes[table + 8..table + 16]);
                b
            };
            let past_end = {
                let mut b = bytes.clone();
                let last = table + 8 * (count - 1);
                b[last..last + 8].copy_from_slice(&(bytes.len() as u64 + 4).to_le_bytes());
                b
            };
            // The first block's size one past the largest a block may have (the file made
            // long enough to hold it): refused, as the exr crate refuses it.
            let oversized = {
                let max = meta.headers[0].max_block_byte_size();
                let first = offset(0) as usize
                    + if matches!(blocks, Blocks::Tiles(_)) {
                        16
                    } else {
                        4
                    };
                let mut b = bytes.clone();
                b[first..first + 4].copy_from_slice(&(max as i32 + 1).to_le_bytes());
                b.resize(b.len() + max + 1, 0);
                b
            };
            std::fs::write(&path, oversized).unwrap();
            let before = READ_AT_OFFSETS.get();
            assert!(read_hdr_image(&path).is_err(), "{compression:?} oversized");
            assert_eq!(READ_AT_OFFSETS.get(), before, "{compression:?} oversized");
            for (what, b) in [("swapped", swapped), ("past the end", past_end)] {
                std::fs::write(&path, b).unwrap();
                let before = READ_AT_OFFSETS.get();
                let got = read_hdr_image(&path).unwrap();
                assert_eq!(READ_AT_OFFSETS.get(), before, "{compression:?} {what}");
                assert_same_bits(&got, &want, &format!("{compression:?} {what}"), &path);
            }
        }
        // A header of 300 KB (a long comment): its end found, the file read at its offsets.
        let encoding = Encoding {
            compression: Compression::ZIP1,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Decreasing,
        };
        exr_file(
            &path,
            (40, 50),
            &["R", "G", "B"],
            SampleType::F32,
            encoding,
            (3, -7),
        );
        let mut image = read_all_flat_layers_from_file(&path).unwrap();
        image.layer_data[0].attributes.comments = Some(Text::from("x".repeat(300_000).as_str()));
        std::fs::remove_file(&path).unwrap();
        image.write().to_file(&path).unwrap();
        let before = READ_AT_OFFSETS.get();
        let got = read_hdr_image(&path).unwrap();
        assert_eq!(READ_AT_OFFSETS.get(), before + 1);
        let (_, _, want) = exr_crate_reference(&path);
        assert_same_bits(&got, &want, "a long header", &path);
    }

    /// `bytes` with one to four bits flipped in their last three quarters (where the pixel
    /// data lies), drawn from the xorshift state `state`.
    fn damaged(bytes: &[u8], state: &mut u64) -> Vec<u8> {
        let mut next = || {
            *state ^= *state << 13;
            *state ^= *state >> 7;
            *state ^= *state << 17;
            *state
        };
        let mut out = bytes.to_vec();
        let from = bytes.len() / 4;
        for _ in 0..1 + next() % 4 {
            let at = from + (next() as usize) % (bytes.len() - from);
            out[at] ^= 1 << (next() % 8);
        }
        out
    }

    /// PIZ blocks with bytes changed at random (fixed seed): reading never panics, refuses
    /// exactly the damaged files the exr crate's reader refuses, and reads the others to the
    /// same values.
    #[test]
    fn damaged_piz_blocks_read_or_fail_cleanly() {
        use exr::meta::attribute::LineOrder;
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        let encoding = Encoding {
            compression: Compression::PIZ,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        };
        // A smooth image in steps of 1/8, which PIZ compresses (noise would be stored raw).
        let (w, h) = (61, 70);
        let channels: Vec<AnyChannel<FlatSamples>> = ["B", "G", "R"]
            .iter()
            .enumerate()
            .map(|(c, name)| {
                let v = (0..w * h).map(|i| {
                    let (x, y) = ((i % w) as f32, (i / w) as f32);
                    let v = (x * 0.05 + c as f32).sin() * (y * 0.07).cos() * 4.0 + 5.0;
                    f16::from_f32((v * 8.0).round() / 8.0)
                });
                AnyChannel::new(*name, FlatSamples::F16(v.collect()))
            })
            .collect();
        let layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            encoding,
            AnyChannels::sort(channels.into()),
        );
        Image::from_layer(layer).write().to_file(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.len() < w * h * 6 / 2, "PIZ compressed the image");
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let (mut failed, mut agreed, mut stricter) = (0, 0, 0);
        for _ in 0..300 {
            std::fs::write(&path, damaged(&bytes, &mut state)).unwrap();
            let ours = read_hdr_image(&path);
            let theirs = read_all_flat_layers_from_file(&path);
            match (ours, theirs) {
                (Err(_), Ok(_)) => stricter += 1,
                (Err(_), Err(_)) => failed += 1,
                (Ok(img), Ok(_)) => {
                    let (_, _, want) = exr_crate_reference(&path);
                    for (a, b) in img.as_raw().iter().zip(&want) {
                        assert_eq!(a.to_bits(), b.to_bits());
                    }
                    agreed += 1;
                }
                (Ok(_), Err(e)) => panic!("read a file the exr crate refuses: {e}"),
            }
        }
        println!(
            "{failed} damaged files refused by both readers, {agreed} read as the exr crate \
             reads them, {stricter} refused only here"
        );
        assert!(failed > 50 && stricter == 0, "{failed} {stricter}");
    }

    /// Damaged blocks of every compression the exr crate writes, scan lines and tiles, half
    /// and float (bytes changed at random, fixed seed): each read gives an image or an
    /// error, never a panic, also where overflow checks are on (the exr crate's B44 decoder
    /// panics on overflow there; that panic is caught and becomes the error).
    #[test]
    fn damaged_blocks_of_every_compression_never_panic() {
        use exr::meta::attribute::{LineOrder, SampleType};
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let compressions = [
            Compression::RLE,
            Compression::ZIP1,
            Compression::ZIP16,
            Compression::PXR24,
            Compression::B44,
            Compression::B44A,
            Compression::PIZ,
        ];
        let mut errors = 0;
        for compression in compressions {
            for blocks in [Blocks::ScanLines, Blocks::Tiles(Vec2(16, 16))] {
                for ty in [SampleType::F16, SampleType::F32] {
                    let line_order = LineOrder::Increasing;
                    let encoding = Encoding {
                        compression,
                        blocks,
                        line_order,
                    };
                    exr_file(&path, (61, 70), &["R", "G", "B"], ty, encoding, (0, 0));
                    let bytes = std::fs::read(&path).unwrap();
                    for _ in 0..40 {
                        std::fs::write(&path, damaged(&bytes, &mut state)).unwrap();
                        let read = std::panic::catch_unwind(|| read_hdr_image(&path).is_err());
                        let what = format!("{compression:?} {blocks:?} {ty:?}");
                        errors += usize::from(read.expect(&what));
                    }
                }
            }
        }
        assert!(errors > 100, "{errors} damaged files refused");
    }

    /// A file cut inside its pixel data is an error from the block reader, not a panic.
    #[test]
    fn truncated_exr_blocks_are_an_error() {
        use exr::meta::attribute::{LineOrder, SampleType};
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        let encoding = Encoding {
            compression: Compression::ZIP16,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        };
        exr_file(
            &path,
            (300, 40),
            &["R", "G", "B"],
            SampleType::F16,
            encoding,
            (0, 0),
        );
        let bytes = std::fs::read(&path).unwrap();
        for cut in [bytes.len() - 1, bytes.len() * 3 / 4, bytes.len() / 2] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            assert!(read_hdr_image(&path).is_err(), "cut at {cut}");
        }
    }

    /// The fast path is the one taken for run-length files (the integration tests check
    /// the values, whichever path reads them): the image crate's encoder writes run-length
    /// scanlines from width 8; the data start found here is where its decoder stops; the
    /// rows decode, to its values.
    #[test]
    fn run_length_files_take_the_parallel_path() {
        let (w, h) = (37u32, 5u32);
        let px: Vec<image::Rgb<f32>> = (0..w * h)
            .map(|i| image::Rgb([(i % 7) as f32, 0.25 * (i % 3) as f32, 1e3 / (1 + i) as f32]))
            .collect();
        let mut file = b"VIEW= -vf x\n".to_vec();
        image::codecs::hdr::HdrEncoder::new(&mut file)
            .encode(&px, w as usize, h as usize)
            .unwrap();
        let start = find(&file, b"#?").unwrap();
        let mut cursor = std::io::Cursor::new(&file[start..]);
        drop(image::codecs::hdr::HdrDecoder::new(&mut cursor).unwrap());
        let at = radiance_data_start(&file, start).unwrap();
        assert_eq!(at, start + cursor.position() as usize);
        let starts = rle_row_starts(&file[at..], w, h).expect("run-length rows");
        let source = HdrSource {
            width: w,
            height: h,
            inner: Source::Rgbe {
                data: file[at..].to_vec(),
                starts,
            },
        };
        // Row by row (the tone-mapping passes) and whole (the image readers).
        let mut by_rows = vec![0.0f32; (3 * w * h) as usize];
        let mut scratch = RowScratch::default();
        for (y, row) in by_rows.chunks_exact_mut(3 * w as usize).enumerate() {
            source.decode_row(y, &mut scratch, row);
        }
        let ours = source.into_image();
        let d = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(&file[start..])).unwrap();
        let theirs = image::DynamicImage::from_decoder(d).unwrap().into_rgb32f();
        assert_eq!(ours.as_raw(), theirs.as_raw());
        assert_eq!(&by_rows, theirs.as_raw());
    }

    /// The luminance straight from the RGBE bytes is that of the decoded values, bit for
    /// bit, for every exponent (both sides of the direct formula's threshold, the subnormal
    /// scales included) and mantissas across their range.
    #[test]
    fn rgbe_luminance_is_that_of_the_decoded_values() {
        let mantissas: Vec<u8> = (0..=255u8)
            .step_by(3)
            .chain([1, 2, 127, 128, 254])
            .collect();
        for e in 0..=255u8 {
            let mut px = Vec::new();
            for &r in &mantissas {
                for &g in &mantissas {
                    px.push([r, g, mantissas[(usize::from(r) + 3 * usize::from(g)) % 91]]);
                }
            }
            let w = px.len();
            // One scan line: each component as literal runs of at most 128 bytes.
            let mut line = Vec::new();
            for c in 0..4 {
                let plane: Vec<u8> = px.iter().map(|p| if c < 3 { p[c] } else { e }).collect();
                for run in plane.chunks(128) {
                    line.push(run.len() as u8);
                    line.extend_from_slice(run);
                }
            }
            let mut planes = vec![0u8; 4 * w];
            let mut rgb = vec![0.0f32; 3 * w];
            decode_rgbe_row(&line, 0, &mut planes, &mut rgb);
            let mut lum = vec![0.0f32; w];
            rgbe_luminance_row(&line, 0, &mut planes, &mut lum);
            for (i, (l, p)) in lum.iter().zip(rgb.chunks_exact(3)).enumerate() {
                let want = crate::luminance([p[0], p[1], p[2]]);
                assert_eq!(l.to_bits(), want.to_bits(), "e {e}, pixel {:?}", px[i]);
            }
        }
    }
}
