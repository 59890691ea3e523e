//! The global operators over the rows of an `HdrSource` (the CLI's 8-bit PNG path: no
//! floating-point image, a Radiance file kept as its own bytes) give the same codes and
//! statistics as the whole-image path (`CleanImage` + `apply_clean_srgb8`), whose values
//! are tested against the reference implementations elsewhere.

use std::path::{Path, PathBuf};

use blueshift_tonemap::io::{HdrSource, Limits, read_hdr_image, read_hdr_source_with};
use blueshift_tonemap::{
    CleanImage, DragoParams, LinearParams, Operator, ReinhardLocalParams, ReinhardParams, Roi,
};
use image::{Rgb, Rgb32FImage};

fn crop(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn global_operators(w: u32, h: u32) -> Vec<Operator> {
    let roi = Roi {
        x_px: w as f32 * 0.3,
        y_px: h as f32 * 0.6,
        radius_px: w.min(h) as f32 * 0.25,
    };
    vec![
        Operator::Drago(DragoParams::default()),
        Operator::Drago(DragoParams {
            bias: 0.7,
            exposure_stops: 1.5,
            roi: Some(roi),
            saturation: 0.6,
            ..DragoParams::default()
        }),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::Reinhard(ReinhardParams {
            key: 0.36,
            white: Some(3.0),
            saturation: 1.4,
        }),
        Operator::Linear(LinearParams::default()),
        Operator::Linear(LinearParams {
            exposure_stops: -0.5,
            white: Some(2.0),
        }),
    ]
}

/// Every global operator on `src`: the rows' codes and statistics are the whole image's.
fn rows_equal_whole_image(src: &HdrSource, img: &Rgb32FImage, what: &str) {
    let clean = CleanImage::new(img);
    for op in global_operators(img.width(), img.height()) {
        let whole = op.apply_clean_srgb8(&clean).unwrap();
        let (codes, stats) = op
            .apply_rows_srgb8(src)
            .unwrap()
            .unwrap_or_else(|| panic!("{what}: {} declined", op.name()));
        assert!(codes == whole, "{what}: {op:?} codes differ");
        assert_eq!(stats, clean.stats(), "{what}: {op:?}");
        assert_eq!(stats.dynamic_range(), clean.dynamic_range());
    }
}

fn source(path: &Path) -> HdrSource {
    read_hdr_source_with(path, &Limits::default()).unwrap()
}

#[test]
fn a_radiance_file_is_tone_mapped_from_its_own_bytes_as_from_its_image() {
    // The committed crop of Debevec's memorial.hdr (run-length scan lines, a 1e4 range).
    let path = crop("memorial_crop_64x96.hdr");
    let src = source(&path);
    assert!(src.is_compact());
    rows_equal_whole_image(&src, &read_hdr_image(&path).unwrap(), "memorial crop");

    // A wider one written here, with black pixels (e = 0) and a huge range.
    let (w, h) = (301u32, 7u32);
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        if (x + y) % 17 == 0 {
            Rgb([0.0; 3])
        } else {
            let l = (f64::from(x) * 0.07 - 9.0 + f64::from(y)).exp() as f32;
            Rgb([l, l * 0.5 + 1e-3, l * (1.0 + (x % 5) as f32)])
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wide.hdr");
    blueshift_tonemap::io::write_radiance_hdr(&path, &img).unwrap();
    let src = source(&path);
    assert!(src.is_compact());
    rows_equal_whole_image(&src, &read_hdr_image(&path).unwrap(), "wide");
    // As a half-float EXR within half's range, clean (its second pass skips the
    // dirty-input rule). Beyond the range, values become +Inf: the rows decline.
    let path = dir.path().join("wide.exr");
    let half = |img: &Rgb32FImage| {
        blueshift_tonemap::io::write_exr(&path, img, blueshift_tonemap::io::ExrPrecision::Half)
            .unwrap();
    };
    half(&img);
    let drago = Operator::Drago(DragoParams::default());
    assert!(drago.apply_rows(&source(&path)).unwrap().is_none());
    let mut img = img;
    img.pixels_mut().for_each(|p| p.0 = p.0.map(|c| c.min(6e4)));
    half(&img);
    let src = source(&path);
    assert!(src.is_compact());
    rows_equal_whole_image(&src, &read_hdr_image(&path).unwrap(), "wide EXR");
}

#[test]
fn dirty_images_are_cleaned_per_row_as_the_whole_image_is() {
    // The committed crop of the desk photograph (EXR PIZ, with negative values), and a
    // synthetic image with NaN and negatives in every channel.
    let path = crop("desk_crop_64x64.exr");
    let src = source(&path);
    // Its decompressed half-float blocks.
    assert!(src.is_compact());
    let img = read_hdr_image(&path).unwrap();
    rows_equal_whole_image(&src, &img, "desk crop");
    let clean = CleanImage::new(&img);
    assert!(clean.report.total() > 0, "the desk crop is dirty");

    let dirty = Rgb32FImage::from_fn(40, 9, |x, y| {
        let v = 0.01 * (1 + x * y) as f32;
        match (x + 3 * y) % 7 {
            0 => Rgb([f32::NAN, v, v]),
            1 => Rgb([v, -v, v]),
            2 => Rgb([v, v, -0.0]),
            _ => Rgb([v, 2.0 * v, 0.5 * v]),
        }
    });
    rows_equal_whole_image(
        &HdrSource::from_image(dirty.clone()),
        &dirty,
        "NaN and negatives",
    );
}

/// OpenEXR files whose dirty values sit in a few rows only (the other blocks known clean
/// by their bits, which skip the dirty-input rule): the rows match the whole image in every
/// compression, half and float, scan lines and tiles; one +Inf anywhere still sends the
/// image to the whole-image path.
#[test]
fn exr_blocks_known_clean_skip_only_what_the_rule_would_not_change() {
    use exr::prelude::*;
    let (w, h) = (37usize, 45usize);
    let dirty = Rgb32FImage::from_fn(w as u32, h as u32, |x, y| {
        let v = 0.02 * (1 + x + 3 * y) as f32;
        match (x, y) {
            (5, 3) => Rgb([f32::NAN, v, v]),
            (36, 20) => Rgb([v, -v, v]),
            (0, 44) => Rgb([v, v, -1e-3]),
            (9, 30) => Rgb([-0.0, v, v]),
            _ => Rgb([v, 2.0 * v, 0.5 * v]),
        }
    });
    let mut inf = dirty.clone();
    inf.put_pixel(17, 33, Rgb([1.0, f32::INFINITY, 1.0]));
    let dir = tempfile::tempdir().unwrap();
    let drago = Operator::Drago(DragoParams::default());
    for compression in [
        Compression::Uncompressed,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::RLE,
    ] {
        for blocks in [Blocks::ScanLines, Blocks::Tiles(Vec2(16, 8))] {
            for half in [true, false] {
                let what = format!("{compression:?} {blocks:?} half {half}");
                for (img, name) in [(&dirty, "dirty"), (&inf, "inf")] {
                    let path = dir.path().join(format!("{name}.exr"));
                    let pixel = |p: Vec2<usize>| img.get_pixel(p.x() as u32, p.y() as u32).0;
                    let encoding = Encoding {
                        compression,
                        blocks,
                        line_order: LineOrder::Increasing,
                    };
                    let attributes = LayerAttributes::default();
                    if half {
                        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
                            pixel(p).map(f16::from_f32).into()
                        });
                        let layer = Layer::new((w, h), attributes, encoding, channels);
                        Image::from_layer(layer).write().to_file(&path).unwrap();
                    } else {
                        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
                            <(f32, f32, f32)>::from(pixel(p))
                        });
                        let layer = Layer::new((w, h), attributes, encoding, channels);
                        Image::from_layer(layer).write().to_file(&path).unwrap();
                    }
                    let src = source(&path);
                    if name == "dirty" {
                        rows_equal_whole_image(&src, &read_hdr_image(&path).unwrap(), &what);
                    } else {
                        assert!(drago.apply_rows_srgb8(&src).unwrap().is_none(), "{what}");
                    }
                }
            }
        }
    }
}

#[test]
fn the_rows_decline_what_needs_the_whole_image() {
    let img = Rgb32FImage::from_fn(8, 4, |x, _| Rgb([x as f32; 3]));
    // Local operators.
    let local = Operator::ReinhardLocal(ReinhardLocalParams::default());
    assert!(
        local
            .apply_rows_srgb8(&HdrSource::from_image(img.clone()))
            .unwrap()
            .is_none()
    );
    // +Inf (its replacement is the whole image's finite maximum).
    let mut inf = img.clone();
    inf.put_pixel(3, 2, Rgb([f32::INFINITY, 1.0, 1.0]));
    let drago = Operator::Drago(DragoParams::default());
    assert!(
        drago
            .apply_rows_srgb8(&HdrSource::from_image(inf))
            .unwrap()
            .is_none()
    );
    // No lit pixel.
    let black = Rgb32FImage::new(8, 4);
    assert!(
        drago
            .apply_rows_srgb8(&HdrSource::from_image(black))
            .unwrap()
            .is_none()
    );
    // Bad parameters and empty images are errors, as on the whole image.
    let bad = Operator::Drago(DragoParams {
        bias: 2.0,
        ..DragoParams::default()
    });
    assert!(
        bad.apply_rows_srgb8(&HdrSource::from_image(img.clone()))
            .is_err()
    );
    assert!(
        drago
            .apply_rows_srgb8(&HdrSource::from_image(Rgb32FImage::new(0, 3)))
            .is_err()
    );
    // A region of interest without a lit pixel: the whole image's error.
    let dark_roi = Operator::Drago(DragoParams {
        roi: Some(Roi {
            x_px: 0.5,
            y_px: 0.5,
            radius_px: 0.4,
        }),
        ..DragoParams::default()
    });
    let whole = dark_roi.apply_clean_srgb8(&CleanImage::new(&img));
    let rows = dark_roi.apply_rows_srgb8(&HdrSource::from_image(img));
    assert_eq!(
        whole.unwrap_err().to_string(),
        rows.unwrap_err().to_string()
    );
}

/// The PNG the rows write (each part of its stream compressed by the thread that made its
/// rows) is the file `write_rgb8_png` makes of the codes, and decodes (PNG crate) to them.
#[test]
fn the_rows_png_is_the_png_of_the_codes() {
    let dir = tempfile::tempdir().unwrap();
    // Tall enough for several parts of the stream (512 KiB of rows each).
    let (w, h) = (640u32, 700u32);
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        let l = (f64::from(x) * 0.013).sin().exp2() as f32 * (1.0 + f64::from(y) * 0.01) as f32;
        Rgb([l, 0.7 * l, 0.2 + 0.1 * l])
    });
    let path = dir.path().join("in.hdr");
    blueshift_tonemap::io::write_radiance_hdr(&path, &img).unwrap();
    // The same as a half-float EXR (clean: the second pass skips the dirty-input rule).
    let exr = dir.path().join("in.exr");
    blueshift_tonemap::io::write_exr(&exr, &img, blueshift_tonemap::io::ExrPrecision::Half)
        .unwrap();
    for file in [
        path,
        exr,
        crop("memorial_crop_64x96.hdr"),
        crop("desk_crop_64x64.exr"),
    ] {
        let src = source(&file);
        let (w, h) = src.dimensions();
        for op in global_operators(w, h) {
            let t = op.apply_rows(&src).unwrap().unwrap();
            let codes = t.srgb8();
            let from_rows = dir.path().join("rows.png");
            let from_codes = dir.path().join("codes.png");
            t.write_png(&from_rows).unwrap();
            let pic = image::RgbImage::from_raw(w, h, codes.clone()).unwrap();
            blueshift_tonemap::io::write_rgb8_png(&from_codes, &pic).unwrap();
            let a = std::fs::read(&from_rows).unwrap();
            assert!(a == std::fs::read(&from_codes).unwrap(), "{file:?} {op:?}");
            // The same bytes on one thread and on three.
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let other = dir.path().join("threads.png");
                pool.install(|| {
                    let t = op.apply_rows(&src).unwrap().unwrap();
                    t.write_png(&other).unwrap();
                });
                assert!(a == std::fs::read(&other).unwrap(), "{threads} threads");
            }
            let decoded = image::load_from_memory(&a).unwrap().into_rgb8();
            assert!(decoded.as_raw() == &codes, "{file:?} {op:?}");
        }
    }
}
