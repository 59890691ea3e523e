//! I/O: round trips, the real photographs of shared/data, and bad files.

use std::path::PathBuf;

use blueshift_tonemap::io::*;
use blueshift_tonemap::{Error, Plane, dynamic_range};
use image::{Rgb, Rgb32FImage};

/// The full photographs of `shared/data/hdr-photos`, when the checkout sits beside `shared/`.
/// Tests that need them say so on stderr and return when they are absent; the committed
/// crops in `tests/data/` (see `tests/data/SOURCE.md`) keep the dirty-input tests running.
fn data_dir() -> Option<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let found = [
        "../../shared/data/hdr-photos",
        "../../../shared/data/hdr-photos",
    ]
    .iter()
    .map(|up| root.join(up))
    .find(|p| p.is_dir());
    if found.is_none() {
        eprintln!(
            "shared/data/hdr-photos not found beside the repository: full-photo checks skipped"
        );
    }
    found
}

fn crop(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

#[test]
fn committed_crops_of_the_real_photographs_read_and_stay_dirty() {
    // Desk.exr (576..640, 808..872): 3,101 of its 4,096 pixels have a negative channel.
    let desk = read_hdr_image(crop("desk_crop_64x64.exr")).unwrap();
    assert_eq!(desk.dimensions(), (64, 64));
    let negative = desk
        .pixels()
        .filter(|p| p.0.iter().any(|&v| v < 0.0))
        .count();
    assert_eq!(negative, 3101);
    let memorial = read_hdr_image(crop("memorial_crop_64x96.hdr")).unwrap();
    assert_eq!(memorial.dimensions(), (64, 96));
    assert!(
        memorial
            .pixels()
            .all(|p| p.0.iter().all(|v| v.is_finite() && *v >= 0.0))
    );
}

fn ramp() -> Rgb32FImage {
    Rgb32FImage::from_fn(13, 7, |x, y| {
        let v = 10f32.powf(x as f32 / 3.0 - 2.0) * (1.0 + y as f32 * 0.1);
        Rgb([v, v * 0.5, v * 2.0])
    })
}

#[test]
fn real_photographs_have_the_documented_sizes_and_luminance_ranges() {
    // shared/data/hdr-photos/SOURCE.md: size, Y max, and Desk's 4,837 negative pixels.
    let Some(dir) = data_dir() else { return };
    for (name, w, h, ymax) in [
        ("Desk.exr", 644, 874, 201.7),
        ("MtTamWest.exr", 1214, 732, 3.89),
        ("memorial.hdr", 512, 768, 223.0),
    ] {
        let img = read_hdr_image(dir.join(name)).unwrap();
        assert_eq!(img.dimensions(), (w, h), "{name}");
        let dr = dynamic_range(&img).unwrap();
        assert!(
            (f64::from(dr.max) / ymax - 1.0).abs() < 0.01,
            "{name}: Y max {}",
            dr.max
        );
    }
    let desk = read_hdr_image(dir.join("Desk.exr")).unwrap();
    let negative = Plane::luminance_of(&desk)
        .data
        .iter()
        .filter(|&&v| v < 0.0)
        .count();
    assert_eq!(negative, 4837);
}

#[test]
fn exr_pfm_and_radiance_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let img = ramp();
    let p = dir.path().join("a.exr");
    write_exr(&p, &img, ExrPrecision::Float).unwrap();
    assert_eq!(read_hdr_image(&p).unwrap(), img);
    write_exr(&p, &img, ExrPrecision::Half).unwrap();
    for (a, b) in read_hdr_image(&p)
        .unwrap()
        .as_raw()
        .iter()
        .zip(img.as_raw())
    {
        assert!((a / b - 1.0).abs() < 1e-3, "half: {a} vs {b}"); // 11-bit mantissa
    }
    let p = dir.path().join("a.pfm");
    write_pfm(&p, &img).unwrap();
    assert_eq!(read_hdr_image(&p).unwrap(), img);
    let p = dir.path().join("a.hdr");
    write_radiance_hdr(&p, &img).unwrap();
    let back = read_hdr_image(&p).unwrap();
    for (a, b) in back.as_raw().chunks(3).zip(img.as_raw().chunks(3)) {
        // RGBE: 8-bit mantissas under the exponent of the largest channel.
        let top = b.iter().copied().fold(0.0f32, f32::max);
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= top / 32.0, "rgbe: {a:?} vs {b:?}");
        }
    }
}

#[test]
fn png_is_srgb_encoded_in_8_and_16_bits() {
    let dir = tempfile::tempdir().unwrap();
    let img = Rgb32FImage::from_fn(3, 1, |x, _| {
        let v = [0.0, srgb_decode(128.0 / 255.0), 1.0][x as usize];
        Rgb([v, v, v])
    });
    let p = dir.path().join("a.png");
    write_png(&p, &img, PngDepth::Eight).unwrap();
    let back = image::open(&p).unwrap().to_rgb8();
    // IEC 61966-2-1: sRGB 0.5 decodes to 0.21404 linear.
    assert!((srgb_decode(0.5) - 0.214_04).abs() < 1e-5);
    assert_eq!(
        [
            back.get_pixel(0, 0)[0],
            back.get_pixel(1, 0)[0],
            back.get_pixel(2, 0)[0]
        ],
        [0, 128, 255]
    );
    write_png(&p, &img, PngDepth::Sixteen).unwrap();
    let back = image::open(&p).unwrap().to_rgb16();
    assert!((i32::from(back.get_pixel(1, 0)[0]) - 32896).abs() <= 1);
}

/// The table-driven 8-bit sRGB code equals `round(255 srgb_encode(v))`, the IEC 61966-2-1
/// formula with `powf`, bit for bit: on every 61st `f32` in [0, 1], at every code's edge
/// (each `f32` whose formula code differs from its predecessor's, and its neighbours), and
/// on the special values.
#[test]
fn srgb8_equals_the_formula_bit_for_bit() {
    let formula = |v: f32| (srgb_encode(v) * 255.0).round() as u8;
    let one = 1.0f32.to_bits();
    let mut edges = 0;
    let mut prev = 0u8;
    let mut bits = 0u32;
    while bits <= one {
        let v = f32::from_bits(bits);
        let f = formula(v);
        assert_eq!(srgb8(v), f, "v = {v:e}");
        if f != prev {
            // A code edge lies between the previous sample and this one: check it exactly.
            let mut b = bits.saturating_sub(61);
            while b <= bits {
                let w = f32::from_bits(b);
                assert_eq!(srgb8(w), formula(w), "edge v = {w:e}");
                b += 1;
            }
            edges += 1;
        }
        prev = f;
        bits += 61;
    }
    assert_eq!(edges, 255, "every code 1..=255 is reached");
    for v in [
        -1.0,
        -0.0,
        0.0,
        f32::MIN_POSITIVE,
        1e-45,
        0.5,
        0.999_999_9,
        1.0,
        1.5,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ] {
        assert_eq!(srgb8(v), formula(v), "v = {v:e}");
    }
}

/// The PNG writer's bytes decode to the formula's codes (every pixel of a ramp with NaN,
/// negative and over-range values), in 8 and 16 bits.
#[test]
fn png_pixels_are_the_formulas_codes() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (97u32, 31u32);
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        let v = (x as f32 / (w - 1) as f32).powi(3) * 1.2 - 0.1;
        let special = [f32::NAN, f32::INFINITY, -2.0][(x as usize + y as usize) % 3];
        Rgb([v, if y == 5 { special } else { v * 0.5 }, (y as f32) / 40.0])
    });
    let p = dir.path().join("ramp.png");
    write_png(&p, &img, PngDepth::Eight).unwrap();
    let back = image::open(&p).unwrap().to_rgb8();
    for (a, b) in back.as_raw().iter().zip(img.as_raw()) {
        assert_eq!(*a, (srgb_encode(*b) * 255.0).round() as u8, "{b}");
    }
    write_png(&p, &img, PngDepth::Sixteen).unwrap();
    let back = image::open(&p).unwrap().to_rgb16();
    for (a, b) in back.as_raw().iter().zip(img.as_raw()) {
        assert_eq!(*a, (srgb_encode(*b) * 65535.0).round() as u16, "{b}");
    }
}

/// The real OpenEXR photographs (written by OpenEXR itself, PIZ) read to the exr
/// crate's own reader's values, bit for bit.
#[test]
fn real_exr_photographs_read_as_the_exr_crate_reads_them() {
    use exr::prelude::*;
    let Some(dir) = data_dir() else { return };
    for name in ["Desk.exr", "MtTamWest.exr"] {
        let path = dir.join(name);
        let img = read_hdr_image(&path).unwrap();
        let reference = read_all_flat_layers_from_file(&path).unwrap();
        let layer = &reference.layer_data[0];
        let find = |n: &str| {
            let c = layer
                .channel_data
                .list
                .iter()
                .find(|c| c.name.to_string() == n);
            c.unwrap().sample_data.values_as_f32().collect::<Vec<f32>>()
        };
        let (r, g, b) = (find("R"), find("G"), find("B"));
        assert_eq!(img.as_raw().len(), 3 * r.len(), "{name}");
        for (i, p) in img.as_raw().chunks_exact(3).enumerate() {
            assert_eq!(
                [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()],
                [r[i].to_bits(), g[i].to_bits(), b[i].to_bits()],
                "{name} pixel {i}"
            );
        }
    }
}

#[test]
fn luminance_only_exr_reads_as_grey() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("y.exr");
    let ys: Vec<f32> = (0..20).map(|i| i as f32 * 0.5).collect();
    let channel = AnyChannel::new("Y", FlatSamples::F32(ys.clone()));
    let layer = Layer::new(
        (5, 4),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(vec![channel].into()),
    );
    Image::from_layer(layer).write().to_file(&p).unwrap();
    let img = read_hdr_image(&p).unwrap();
    assert_eq!(img.get_pixel(3, 2).0, [ys[13]; 3]);
}

#[test]
fn exr_sequence_frames_are_numbered_and_listed_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let mut seq =
        ExrSequenceWriter::new(dir.path().join("movie"), "frame_", ExrPrecision::Half).unwrap();
    for _ in 0..12 {
        seq.push(&ramp()).unwrap();
    }
    let frames = list_exr_sequence(dir.path().join("movie"), "frame_").unwrap();
    assert_eq!(frames.len(), 12);
    assert!(frames[11].ends_with("frame_0011.exr"));
    assert!(read_hdr_image(&frames[3]).is_ok());
}

#[test]
fn invalid_files_error_without_panic() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("g.exr");
    write_exr(&good, &ramp(), ExrPrecision::Half).unwrap();
    let exr_bytes = std::fs::read(&good).unwrap();
    let pfm = dir.path().join("g.pfm");
    write_pfm(&pfm, &ramp()).unwrap();
    let pfm_bytes = std::fs::read(&pfm).unwrap();
    let memorial = std::fs::read(crop("memorial_crop_64x96.hdr")).unwrap();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("truncated.exr", exr_bytes[..exr_bytes.len() / 2].to_vec()),
        ("header-only.exr", exr_bytes[..40].to_vec()),
        ("truncated.pfm", pfm_bytes[..pfm_bytes.len() - 10].to_vec()),
        (
            "huge.pfm",
            b"PF\n4000000000 4000000000\n-1.0\n\0\0\0\0".to_vec(),
        ),
        ("nan-scale.pfm", b"PF\n2 2\nnan\n".to_vec()),
        ("truncated.hdr", memorial[..memorial.len() / 3].to_vec()),
        ("garbage.hdr", b"hello, not an image".to_vec()),
        ("empty.exr", Vec::new()),
    ];
    for (name, bytes) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let r = read_hdr_image(&p);
        assert!(
            matches!(
                r,
                Err(Error::Invalid { .. } | Error::Unsupported { .. } | Error::Limits { .. })
            ),
            "{name}: {r:?}"
        );
    }
    assert!(matches!(
        read_hdr_image(dir.path().join("missing.exr")),
        Err(Error::Io { .. })
    ));
}

#[test]
fn every_operator_maps_the_dirty_desk_crop_to_a_finite_non_black_image() {
    use blueshift_tonemap::*;
    let desk = read_hdr_image(crop("desk_crop_64x64.exr")).unwrap();
    for op in [
        Operator::Linear(LinearParams::default()),
        Operator::Drago(DragoParams::default()),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::ReinhardLocal(ReinhardLocalParams::default()),
        Operator::Durand(DurandParams::default()),
        Operator::Fattal(FattalParams::default()),
    ] {
        let out = op.apply(&desk).unwrap();
        assert!(
            out.as_raw().iter().all(|v| v.is_finite() && *v >= 0.0),
            "{op:?}"
        );
        let mean =
            out.as_raw().iter().map(|&v| f64::from(v)).sum::<f64>() / out.as_raw().len() as f64;
        assert!(mean > 1e-3, "{op:?}: black frame (mean {mean})");
    }
}

/// The image crate's Radiance decoder (the reference the parallel reader must equal).
fn image_crate_hdr(bytes: &[u8]) -> Rgb32FImage {
    let start = bytes.windows(2).position(|w| w == b"#?").unwrap();
    let d = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(&bytes[start..])).unwrap();
    image::DynamicImage::from_decoder(d).unwrap().into_rgb32f()
}

/// A Radiance file of raw RGBE pixels, every scanline in the per-component run-length
/// encoding: each component alternates a run (a repeated byte, when one follows) and a
/// literal stretch of up to `max_literal` bytes. Written here from the format's
/// description, independently of both readers.
fn rle_hdr(w: usize, rgbe: &[[u8; 4]], max_literal: usize) -> Vec<u8> {
    let h = rgbe.len() / w;
    let mut out = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n").into_bytes();
    for row in rgbe.chunks_exact(w) {
        out.extend_from_slice(&[2, 2, (w >> 8) as u8, (w & 255) as u8]);
        for c in 0..4 {
            let comp: Vec<u8> = row.iter().map(|p| p[c]).collect();
            let mut x = 0;
            while x < w {
                let mut run = 1;
                while x + run < w && run < 127 && comp[x + run] == comp[x] {
                    run += 1;
                }
                if run >= 3 {
                    out.extend_from_slice(&[128 + run as u8, comp[x]]);
                    x += run;
                } else {
                    let n = max_literal.min(w - x);
                    out.push(n as u8);
                    out.extend_from_slice(&comp[x..x + n]);
                    x += n;
                }
            }
        }
    }
    out
}

/// The parallel reader of run-length Radiance scanlines gives the image crate's values
/// bit for bit: random pixels with every exponent (0 black, 1 the subnormal special case,
/// up to 255), runs and literal stretches of every length, widths from 1 to past one
/// literal stretch; files the image crate's own encoder wrote (run-length scanlines from
/// width 8, flat ones below, which the image crate decodes); and the real memorial crop.
/// Truncated run-length data is an error, not a panic.
#[test]
fn radiance_rle_rows_read_in_parallel_equal_the_image_crate() {
    let dir = tempfile::tempdir().unwrap();
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for (w, h, lit) in [
        (1, 3, 1),
        (7, 5, 2),
        (64, 9, 128),
        (300, 4, 17),
        (129, 3, 128),
    ] {
        let mut px: Vec<[u8; 4]> = (0..w * h)
            .map(|i| {
                let r = next();
                if i % 11 < 4 {
                    // Runs: the same pixel as the previous one.
                    [7, 9, 200, 130]
                } else {
                    [
                        (r >> 8) as u8,
                        (r >> 16) as u8,
                        (r >> 24) as u8,
                        (r >> 32) as u8,
                    ]
                }
            })
            .collect();
        // The exponents with special cases, at the start of the last row.
        let specials = [[255, 1, 0, 0], [3, 4, 5, 1], [1, 1, 1, 2], [9, 9, 9, 255]];
        for (p, s) in px[(h - 1) * w..].iter_mut().zip(specials) {
            *p = s;
        }
        let bytes = rle_hdr(w, &px, lit);
        let p = dir.path().join(format!("r{w}.hdr"));
        std::fs::write(&p, &bytes).unwrap();
        let ours = read_hdr_image(&p).unwrap();
        let theirs = image_crate_hdr(&bytes);
        let bits = |i: &Rgb32FImage| i.as_raw().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(ours.dimensions(), (w as u32, h as u32));
        assert_eq!(bits(&ours), bits(&theirs), "{w}x{h}");
        // Cut inside the pixel data: an error.
        let cut = dir.path().join(format!("cut{w}.hdr"));
        std::fs::write(&cut, &bytes[..bytes.len() - 2]).unwrap();
        assert!(read_hdr_image(&cut).is_err(), "{w}x{h} truncated");
    }
    for (w, h) in [(5u32, 4u32), (8, 3), (97, 31)] {
        let img = Rgb32FImage::from_fn(w, h, |x, y| {
            let v = ((x * 7 + y * 13) % 17) as f32 * 0.37;
            Rgb([v, v * 1e-3, if x % 3 == 0 { 0.0 } else { v * 40.0 }])
        });
        let p = dir.path().join(format!("e{w}.hdr"));
        write_radiance_hdr(&p, &img).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(
            read_hdr_image(&p).unwrap().as_raw(),
            image_crate_hdr(&bytes).as_raw(),
            "{w}x{h}"
        );
    }
    let memorial = crop("memorial_crop_64x96.hdr");
    let bytes = std::fs::read(&memorial).unwrap();
    assert_eq!(
        read_hdr_image(&memorial).unwrap().as_raw(),
        image_crate_hdr(&bytes).as_raw()
    );
}

/// The IDAT chunks of a PNG file, concatenated (its zlib stream).
fn idat_stream(png: &[u8]) -> Vec<u8> {
    let mut at = 8;
    let mut out = Vec::new();
    while at + 8 <= png.len() {
        let len = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
        if &png[at + 4..at + 8] == b"IDAT" {
            out.extend_from_slice(&png[at + 8..at + 8 + len]);
        }
        at += 12 + len;
    }
    out
}

/// PNGs compressed in parallel decode to their samples with the png crate's decoder, and
/// their zlib stream inflates with flate2 (which checks the Adler-32) to the Up-filtered
/// rows: noise (long codes), zeros (runs past 258 bytes), a gradient (runs and literals),
/// RGB and RGBA, 8 and 16 bits, one row, one column, and images of several chunks
/// (`zlib::CHUNK_BYTES`); the bytes do not depend on the thread count.
#[test]
fn parallel_png_compression_round_trips_through_independent_decoders() {
    use std::io::Read;
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut noise = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 24) as u8
    };
    let cases: Vec<(u32, u32, png::ColorType, png::BitDepth, Vec<u8>)> = {
        let mut v = Vec::new();
        for (w, h) in [(1u32, 1u32), (1, 300), (777, 1), (64, 48), (1500, 700)] {
            let n = (w * h) as usize;
            let grad: Vec<u8> = (0..n * 3)
                .map(|i| ((i / 3) % w as usize / 7 + (i / 3) / w as usize / 5) as u8)
                .collect();
            v.push((w, h, png::ColorType::Rgb, png::BitDepth::Eight, grad));
            v.push((
                w,
                h,
                png::ColorType::Rgb,
                png::BitDepth::Eight,
                vec![0; n * 3],
            ));
            let rgba: Vec<u8> = (0..n * 4).map(|_| noise()).collect();
            v.push((w, h, png::ColorType::Rgba, png::BitDepth::Eight, rgba));
            let deep: Vec<u8> = (0..n * 6)
                .map(|i| {
                    if i % 2 == 0 {
                        (i / 6 % 3) as u8
                    } else {
                        noise()
                    }
                })
                .collect();
            v.push((w, h, png::ColorType::Rgb, png::BitDepth::Sixteen, deep));
        }
        v
    };
    // The filter the rows are compressed with is the one the header settings name.
    assert_eq!(PNG_FILTER, png::Filter::Up);
    // Sample layouts the writer does not produce are refused, not written wrong.
    for (color, depth) in [
        (png::ColorType::Indexed, png::BitDepth::Eight),
        (png::ColorType::Grayscale, png::BitDepth::Four),
        (png::ColorType::Grayscale, png::BitDepth::One),
    ] {
        let r = encode_png(Vec::new(), 4, 4, color, depth, &[0; 16]);
        assert!(
            matches!(r, Err(Error::Parameter(_))),
            "{color:?} {depth:?}: {r:?}"
        );
    }
    for (w, h, color, depth, data) in cases {
        let mut png_bytes = Vec::new();
        encode_png(&mut png_bytes, w, h, color, depth, &data).unwrap();
        let what = format!("{w}x{h} {color:?} {depth:?}");
        // The png crate's decoder.
        let dec = png::Decoder::new(std::io::Cursor::new(&png_bytes));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(&buf[..info.buffer_size()], &data[..], "{what}");
        // flate2: the stream and its checksum, to the Up-filtered rows.
        let mut rows = Vec::new();
        flate2::read::ZlibDecoder::new(&idat_stream(&png_bytes)[..])
            .read_to_end(&mut rows)
            .unwrap();
        let row = data.len() / h as usize;
        let mut expect = Vec::new();
        for y in 0..h as usize {
            expect.push(2);
            for x in 0..row {
                let above = if y == 0 { 0 } else { data[(y - 1) * row + x] };
                expect.push(data[y * row + x].wrapping_sub(above));
            }
        }
        assert_eq!(rows, expect, "{what}");
        // One thread: the same bytes.
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let mut again = Vec::new();
        one.install(|| encode_png(&mut again, w, h, color, depth, &data).unwrap());
        assert_eq!(again, png_bytes, "{what}");
    }
}

/// A header that claims more image than its file can hold is refused before the image is
/// allocated (a fuzzer's 8.5 KB PIZ file claimed 40 x 2,097,175 pixels, a 1 GB image): by
/// its block count (16 bytes at least per block) or by its compression's largest ratio.
#[test]
fn exr_headers_claiming_more_than_the_file_holds_are_refused_up_front() {
    let desk = std::fs::read(crop("desk_crop_64x64.exr")).unwrap();
    // The data window, box2i (xmin, ymin, xmax, ymax), after its name, type and size.
    let key = b"dataWindow\0box2i\0\x10\0\0\0";
    let at = desk
        .windows(key.len())
        .position(|w| w == key)
        .expect("the crop has a data window")
        + key.len();
    let forged = |xmax: i32, ymax: i32| {
        let mut b = desk.clone();
        b[at + 8..at + 12].copy_from_slice(&xmax.to_le_bytes());
        b[at + 12..at + 16].copy_from_slice(&ymax.to_le_bytes());
        b
    };
    let dir = tempfile::tempdir().unwrap();
    let limits = Limits::default();
    // 2,000,001 rows of 64 x 64 tiles are 31,251 blocks, at least 500 KB; the file holds
    // 49,570 bytes.
    let tall = dir.path().join("tall.exr");
    std::fs::write(&tall, forged(63, 2_000_000)).unwrap();
    let e = read_exr(&tall, &limits).unwrap_err().to_string();
    assert!(
        e.contains("31251 blocks need at least 500016 bytes, the file holds 49570"),
        "{e}"
    );
    // 1,563 blocks fit, but 100,001 x 64 float RGB pixels are 76.8 MB of samples: more than
    // RLE (at most 128:1) gets from 49,570 bytes.
    let wide = dir.path().join("wide.exr");
    std::fs::write(&wide, forged(100_000, 63)).unwrap();
    let e = read_exr(&wide, &limits).unwrap_err().to_string();
    assert!(e.contains("76800768 bytes of samples"), "{e}");
    // The crop itself, whose samples are 49,152 bytes, still reads.
    let ok = dir.path().join("ok.exr");
    std::fs::write(&ok, forged(63, 63)).unwrap();
    assert_eq!(read_exr(&ok, &limits).unwrap().dimensions(), (64, 64));
}

/// Radiance files in the old encoding (flat pixels with `1 1 1 n` repeat markers) read
/// through the image crate's decoder; a header that claims more scan lines or wider ones
/// than the data holds is refused before that decoder allocates the image.
#[test]
fn old_encoding_radiance_reads_and_a_lying_header_is_refused_up_front() {
    let head = |w: u32, h: u32| format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n");
    // Per line: a literal pixel, a repeat of it 3 times, another literal: 5 pixels.
    // RGBE (128, 64, 32, 129) is (1, 0.5, 0.25); (96, 96, 96, 130) is (1.5, 1.5, 1.5).
    let line = [128u8, 64, 32, 129, 1, 1, 1, 3, 96, 96, 96, 130];
    let mut good = head(5, 2).into_bytes();
    good.extend_from_slice(&line);
    good.extend_from_slice(&line);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("old.hdr");
    std::fs::write(&p, &good).unwrap();
    let img = read_radiance(&p, &Limits::default()).unwrap();
    assert_eq!(img.dimensions(), (5, 2));
    for y in 0..2 {
        for x in 0..4 {
            assert_eq!(img.get_pixel(x, y).0, [1.0, 0.5, 0.25], "({x}, {y})");
        }
        assert_eq!(img.get_pixel(4, y).0, [1.5, 1.5, 1.5]);
    }
    // The same two lines under headers that claim 10,000 lines, or lines of 10,000 pixels
    // (a 120 MB image), or a run past the line's end.
    for (name, w, h) in [("tall", 5, 10_000), ("wide", 10_000, 1_000)] {
        let mut b = head(w, h).into_bytes();
        b.extend_from_slice(&line);
        b.extend_from_slice(&line);
        let p = dir.path().join(format!("{name}.hdr"));
        std::fs::write(&p, &b).unwrap();
        let e = read_radiance(&p, &Limits::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(&format!(
                "the data does not hold the header's {w}x{h} pixels"
            )),
            "{name}: {e}"
        );
    }
    let mut b = head(3, 2).into_bytes();
    b.extend_from_slice(&line);
    b.extend_from_slice(&line);
    let p = dir.path().join("overrun.hdr");
    std::fs::write(&p, &b).unwrap();
    assert!(read_radiance(&p, &Limits::default()).is_err());
}

/// Consecutive repeat markers multiply (the n-th by 256^(n-1)): eight in a row would
/// overflow the image crate's multiplier, so such data is refused before it is decoded, and
/// seven zero-length ones (which repeat nothing) still read.
#[test]
fn radiance_repeat_marker_chains_are_bounded() {
    let head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 2\n".to_vec();
    let dir = tempfile::tempdir().unwrap();
    for (markers, ok) in [(7, true), (8, false), (40, false)] {
        let mut b = head.clone();
        b.extend_from_slice(&[128, 128, 128, 129]);
        for _ in 0..markers {
            b.extend_from_slice(&[1, 1, 1, 0]);
        }
        b.extend_from_slice(&[64, 64, 64, 129]);
        let p = dir.path().join(format!("chain{markers}.hdr"));
        std::fs::write(&p, &b).unwrap();
        let r = read_radiance(&p, &Limits::default());
        assert_eq!(r.is_ok(), ok, "{markers} markers: {r:?}");
        if let Ok(img) = r {
            assert_eq!(img.get_pixel(0, 0).0, [1.0; 3]);
            assert_eq!(img.get_pixel(1, 0).0, [0.5; 3]);
        }
    }
}

/// A Radiance file large enough to be read by several threads at once (8 MiB and more)
/// decodes to the image crate's values.
#[test]
fn large_radiance_files_read_in_pieces_as_the_image_crate_reads_them() {
    let (w, h) = (1700u32, 1400u32);
    // Noise, so the run-length encoding keeps nearly 4 bytes per pixel (about 9.5 MB).
    let px: Vec<Rgb<f32>> = (0..w * h)
        .map(|i| {
            let k = u64::from(i).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40;
            let v = (k % 1000) as f32 * 0.37 + 1e-3;
            Rgb([v, v * 0.5 + (k % 7) as f32, (k % 13) as f32 * 100.0])
        })
        .collect();
    let mut file = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut file)
        .encode(&px, w as usize, h as usize)
        .unwrap();
    assert!(file.len() > 8 << 20, "{} bytes", file.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.hdr");
    std::fs::write(&path, &file).unwrap();
    let ours = read_hdr_image(&path).unwrap();
    assert_eq!(ours.as_raw(), image_crate_hdr(&file).as_raw());
}

/// An uncompressed scan-line file whose second block claims the first block's line (one
/// flipped y): the first line is given twice and the second is missing. OpenEXR's
/// library refuses it; so does blueshift, instead of a band of zeros.
#[test]
fn an_exr_block_given_twice_is_refused() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("dup.exr");
    let channel = |n: &str, v: f32| AnyChannel::new(n, FlatSamples::F32(vec![v; 12]));
    let layer = Layer::new(
        (4, 3),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(vec![channel("R", 1.0), channel("G", 0.5), channel("B", 0.25)].into()),
    );
    Image::from_layer(layer).write().to_file(&p).unwrap();
    assert_eq!(
        read_hdr_image(&p).unwrap().get_pixel(1, 1).0,
        [1.0, 0.5, 0.25]
    );
    // Block 1's leader: line 1, 48 bytes (4 pixels x 3 channels x f32).
    let mut bytes = std::fs::read(&p).unwrap();
    let leader = [1i32.to_le_bytes(), 48i32.to_le_bytes()].concat();
    let at: Vec<usize> = (0..bytes.len() - 8)
        .filter(|&i| bytes[i..i + 8] == leader[..])
        .collect();
    assert_eq!(at.len(), 1, "one block of line 1");
    bytes[at[0]..at[0] + 4].copy_from_slice(&0i32.to_le_bytes());
    std::fs::write(&p, &bytes).unwrap();
    let e = read_hdr_image(&p).unwrap_err().to_string();
    assert!(e.contains("repeats"), "{e}");
}

/// A two-part file whose first part is depth (as renderers write AOVs first) reads its
/// second, colour part; a file with no colour part at all names that.
#[test]
fn a_multi_part_exr_reads_its_first_colour_part() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("parts.exr");
    let flat = |n: &str, v: f32| AnyChannel::new(n, FlatSamples::F32(vec![v; 12]));
    let part = |name: &str, channels: Vec<AnyChannel<FlatSamples>>| {
        Layer::new(
            (4, 3),
            LayerAttributes::named(name),
            Encoding::FAST_LOSSLESS,
            AnyChannels::sort(channels.into()),
        )
    };
    let depth = part("depth", vec![flat("Z", 7.0)]);
    let colour = part(
        "beauty",
        vec![flat("R", 1.0), flat("G", 0.5), flat("B", 0.25)],
    );
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((4, 3))),
        vec![depth.clone(), colour],
    )
    .write()
    .to_file(&p)
    .unwrap();
    let img = read_hdr_image(&p).unwrap();
    assert_eq!(img.get_pixel(2, 1).0, [1.0, 0.5, 0.25]);
    let only_depth = dir.path().join("depth.exr");
    Image::from_layer(depth)
        .write()
        .to_file(&only_depth)
        .unwrap();
    let e = read_hdr_image(&only_depth).unwrap_err().to_string();
    assert!(e.contains("no R, G, B or Y channel"), "{e}");
}

/// Luminance/chroma OpenEXR files (`Y` with `RY`, `BY` sampled 2x2, as OpenEXR's
/// RgbaOutputFile writes them) read as OpenEXR's own RgbaInputFile reconstructs them: its
/// RGB output for each file, dumped by `tests/data/yc/gen.cpp` (OpenEXR 3.1.5), is the
/// reference. Covers ZIP, RLE and uncompressed blocks, alpha, an odd number of chroma samples, a
/// data window off the origin, sharp colour edges (the saturation fix) and Rec. 2020
/// chromaticities.
#[test]
fn luminance_chroma_files_read_as_openexr_reconstructs_them() {
    for (name, w, h) in [
        ("yc_8x6_zip", 8, 6),
        ("yca_8x6_none", 8, 6),
        ("yc_10x6_offset_none", 10, 6),
        ("yc_60x40_zip", 60, 40),
        ("yc_16x12_rec2020_zip", 16, 12),
        ("yc_12x8_rle", 12, 8),
        ("yc_8x4_bottom_zip", 8, 4),
    ] {
        let img = read_hdr_image(crop(&format!("yc/{name}.exr"))).unwrap();
        assert_eq!(img.dimensions(), (w, h), "{name}");
        let want: Vec<f32> = std::fs::read(crop(&format!("yc/{name}.rgba.f32")))
            .unwrap()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let mut worst = 0.0f32;
        let mut grey = true;
        for (p, q) in img.pixels().zip(want.chunks_exact(4)) {
            for c in 0..3 {
                worst = worst.max((p.0[c] - q[c]).abs());
            }
            grey &= p.0[0] == p.0[1] && p.0[1] == p.0[2];
        }
        assert!(!grey, "{name}: read as grey");
        assert_eq!(worst, 0.0, "{name}: differs from OpenEXR by up to {worst}");
    }
}
