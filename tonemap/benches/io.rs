//! Whole-process I/O of `blueshift tonemap` on an 8-megapixel image (3464 x 2309), each
//! against a baseline measured in the same run:
//!
//! - `png_8mp`: the display image to PNG bytes. `image_crate_default` is the writer before
//!   (per-sample `powf` sRGB encoding, `image`'s PNG encoder with its defaults: fdeflate
//!   fast compression, adaptive filtering); `blueshift` is [`io::display_to_srgb8`] plus
//!   [`io::encode_png`]; the other rows are the encoder settings it was chosen from (the
//!   compressed sizes are printed once).
//! - `read_8mp`: a PIZ-compressed half-float EXR and the same image as Radiance RGBE,
//!   read into RGB f32 (the EXR also with `exr`'s decompression forced onto one thread, the
//!   RGBE file also with the image crate's decoder, on one thread).
//! - `process_8mp`: read the EXR (or the RGBE file), apply Drago, write the PNG bytes as
//!   the CLI does (straight to sRGB codes, [`blueshift_tonemap::Operator::apply_clean_srgb8`]),
//!   against the Drago operator alone on the in-memory image (the goal: the whole
//!   process in no more than the operator's time of a peer).

use blueshift_tonemap::io;
use blueshift_tonemap::{DragoParams, Operator};
use criterion::{Criterion, criterion_group, criterion_main};
use image::{Rgb, Rgb32FImage};

fn hash01(i: u64) -> f32 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

/// The operators bench's seeded scene: smooth gradients, a bright disc, 10 % noise.
fn scene(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let mut l = 0.01 + 2.0 * u * v + 0.2 * (20.0 * u).sin().abs();
        if (u - 0.7).powi(2) + (v - 0.3).powi(2) < 0.004 {
            l += 500.0;
        }
        l *= 1.0 + 0.1 * hash01(u64::from(y * w + x));
        Rgb([l * 1.1, l, l * 0.8])
    })
}

/// The writer before: `powf` per sample, then `image`'s encoder with its defaults.
fn png_before(display: &Rgb32FImage) -> Vec<u8> {
    let (w, h) = display.dimensions();
    let rgb = image::RgbImage::from_fn(w, h, |x, y| {
        Rgb(display
            .get_pixel(x, y)
            .0
            .map(|v| (io::srgb_encode(v) * 255.0).round() as u8))
    });
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb8(rgb)
        .write_to(&mut out, image::ImageFormat::Png)
        .expect("png");
    out.into_inner()
}

fn png_with(rgb: &[u8], w: u32, h: u32, c: png::Compression, f: png::Filter) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(c);
    enc.set_filter(f);
    let mut wr = enc.write_header().expect("header");
    wr.write_image_data(rgb).expect("data");
    wr.finish().expect("finish");
    out
}

fn png_after(display: &Rgb32FImage) -> Vec<u8> {
    let (w, h) = display.dimensions();
    let mut out = Vec::new();
    io::encode_png(
        &mut out,
        w,
        h,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        &io::display_to_srgb8(display),
    )
    .expect("png");
    out
}

fn write_half(path: &std::path::Path, img: &Rgb32FImage, compression: exr::prelude::Compression) {
    use exr::prelude::*;
    let owned = img.clone();
    let channels = SpecificChannels::rgb(move |p: Vec2<usize>| {
        let q = owned.get_pixel(p.x() as u32, p.y() as u32).0;
        (
            f16::from_f32(q[0]),
            f16::from_f32(q[1]),
            f16::from_f32(q[2]),
        )
    });
    write_exr(path, img, compression, channels);
}

fn write_float(path: &std::path::Path, img: &Rgb32FImage, compression: exr::prelude::Compression) {
    use exr::prelude::*;
    let owned = img.clone();
    let channels = SpecificChannels::rgb(move |p: Vec2<usize>| {
        let q = owned.get_pixel(p.x() as u32, p.y() as u32).0;
        (q[0], q[1], q[2])
    });
    write_exr(path, img, compression, channels);
}

fn write_exr<C>(
    path: &std::path::Path,
    img: &Rgb32FImage,
    compression: exr::prelude::Compression,
    channels: C,
) where
    C: for<'a> exr::image::write::channels::WritableChannels<'a> + 'static,
{
    use exr::prelude::*;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding {
            compression,
            ..Encoding::default()
        },
        channels,
    );
    Image::from_layer(layer).write().to_file(path).expect("exr");
}

/// The exr crate's own image reader, which `read_hdr_image` used before it read files block
/// by block: on the crate's thread pool, or on one thread.
fn read_exr_crate(path: &std::path::Path, parallel: bool) -> usize {
    use exr::prelude::*;
    let reader = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes();
    let img = if parallel {
        reader.from_file(path)
    } else {
        reader.non_parallel().from_file(path)
    };
    img.expect("exr").layer_data.channel_data.list.len()
}

fn bench(c: &mut Criterion) {
    let (w, h) = (3464u32, 2309u32);
    let hdr = scene(w, h);
    let drago = Operator::Drago(DragoParams::default());
    let display = drago.apply(&hdr).expect("drago");

    // Sizes, once.
    let rgb = io::display_to_srgb8(&display);
    let variants = [
        (
            "fast_adaptive",
            png::Compression::Fast,
            png::Filter::Adaptive,
        ),
        (
            "fast_nofilter",
            png::Compression::Fast,
            png::Filter::NoFilter,
        ),
        ("fast_sub", png::Compression::Fast, png::Filter::Sub),
        ("fast_up", png::Compression::Fast, png::Filter::Up),
        ("fast_paeth", png::Compression::Fast, png::Filter::Paeth),
        ("fastest_up", png::Compression::Fastest, png::Filter::Up),
    ];
    eprintln!("PNG bytes: before {}", png_before(&display).len());
    eprintln!("PNG bytes: blueshift {}", png_after(&display).len());
    for (name, comp, filt) in variants {
        eprintln!(
            "PNG bytes: {name} {}",
            png_with(&rgb, w, h, comp, filt).len()
        );
    }

    let mut g = c.benchmark_group("png_8mp");
    g.sample_size(10);
    g.bench_function("image_crate_default", |b| b.iter(|| png_before(&display)));
    g.bench_function("blueshift", |b| b.iter(|| png_after(&display)));
    g.bench_function("srgb8_only", |b| b.iter(|| io::display_to_srgb8(&display)));
    // The compression alone: blueshift's parallel zlib stream against `fast_up` (the png
    // crate's fdeflate on one thread, the setting before), on the same codes.
    g.bench_function("encode_only", |b| {
        b.iter(|| {
            let mut out = Vec::new();
            io::encode_png(
                &mut out,
                w,
                h,
                png::ColorType::Rgb,
                png::BitDepth::Eight,
                &rgb,
            )
            .expect("png");
            out
        })
    });
    for (name, comp, filt) in variants {
        g.bench_function(name, |b| b.iter(|| png_with(&rgb, w, h, comp, filt)));
    }
    g.finish();

    let dir = tempfile::tempdir().expect("tempdir");
    let exr_path = dir.path().join("scene.exr");
    let hdr_path = dir.path().join("scene.hdr");
    write_half(&exr_path, &hdr, exr::prelude::Compression::PIZ);
    let zip_path = dir.path().join("scene_zip.exr");
    write_half(&zip_path, &hdr, exr::prelude::Compression::ZIP16);
    io::write_radiance_hdr(&hdr_path, &hdr).expect("hdr");
    // Float samples, uncompressed (the blocks read at their offsets by the pool's threads)
    // and PIZ (long Huffman codes for the mantissas' low halves).
    let none32_path = dir.path().join("scene_none32.exr");
    write_float(&none32_path, &hdr, exr::prelude::Compression::Uncompressed);
    let piz32_path = dir.path().join("scene_piz32.exr");
    write_float(&piz32_path, &hdr, exr::prelude::Compression::PIZ);
    let mut g = c.benchmark_group("read_8mp");
    g.sample_size(10);
    // Each file by blueshift, then by the exr crate's own parallel reader.
    for (name, path) in [
        ("exr_piz_half", &exr_path),
        ("exr_zip_half", &zip_path),
        ("exr_none_float", &none32_path),
        ("exr_piz_float", &piz32_path),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| io::read_hdr_image(path).expect("exr"));
        });
        g.bench_function(format!("{name}_exr_crate"), |b| {
            b.iter(|| read_exr_crate(path, true));
        });
    }
    g.bench_function("exr_piz_half_decode_one_thread", |b| {
        b.iter(|| read_exr_crate(&exr_path, false));
    });
    g.bench_function("rgbe", |b| {
        b.iter(|| io::read_hdr_image(&hdr_path).expect("hdr"));
    });
    // The image crate's decoder (one thread), which `rgbe` used before.
    g.bench_function("rgbe_image_crate", |b| {
        b.iter(|| {
            let bytes = std::fs::read(&hdr_path).expect("read");
            let d = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(bytes)).expect("hdr");
            image::DynamicImage::from_decoder(d)
                .expect("decode")
                .into_rgb32f()
        });
    });
    g.finish();

    let mut g = c.benchmark_group("process_8mp");
    g.sample_size(10);
    g.bench_function("drago_operator_alone", |b| {
        b.iter(|| drago.apply(&hdr).expect("drago"));
    });
    // The CLI's path: read, clean, straight to sRGB codes, PNG bytes.
    let whole = |path: &std::path::Path| {
        let clean =
            blueshift_tonemap::CleanImage::from_image(io::read_hdr_image(path).expect("read"));
        let codes = drago.apply_clean_srgb8(&clean).expect("drago");
        let mut out = Vec::new();
        io::encode_png(
            &mut out,
            w,
            h,
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &codes,
        )
        .expect("png");
        out
    };
    g.bench_function("exr_read_drago_png", |b| b.iter(|| whole(&exr_path)));
    g.bench_function("exr_zip_read_drago_png", |b| b.iter(|| whole(&zip_path)));
    g.bench_function("rgbe_read_drago_png", |b| b.iter(|| whole(&hdr_path)));
    // The CLI's path since 2026-12-06 night: the file as an `HdrSource` (a Radiance file
    // kept as its bytes), the statistics from one pass over its rows, then the codes of each
    // part of the PNG stream made and compressed together (into a file: the PNG is not
    // held whole).
    let png = dir.path().join("out.png");
    let rows = |path: &std::path::Path| {
        let src = io::read_hdr_source_with(path, &io::Limits::default()).expect("read");
        let t = drago.apply_rows(&src).expect("drago").expect("global");
        t.write_png(&png).expect("png");
        t.stats
    };
    g.bench_function("exr_rows_drago_png", |b| b.iter(|| rows(&exr_path)));
    g.bench_function("exr_zip_rows_drago_png", |b| b.iter(|| rows(&zip_path)));
    g.bench_function("rgbe_rows_drago_png", |b| b.iter(|| rows(&hdr_path)));
    g.bench_function("exr_none_float_rows_drago_png", |b| {
        b.iter(|| rows(&none32_path))
    });
    g.bench_function("exr_piz_float_rows_drago_png", |b| {
        b.iter(|| rows(&piz32_path))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
