//! Property tests of the operators against analytic truths.

use blueshift_tonemap::ops::durand::{bilateral_direct, fast_bilateral};
use blueshift_tonemap::ops::fattal::compressed_log_luminance;
use blueshift_tonemap::poisson::{laplacian_neumann, solve_poisson_neumann};
use blueshift_tonemap::*;
use image::{Rgb, Rgb32FImage};

/// Counter-based hash to [0, 1): deterministic test inputs without a RNG crate.
fn hash01(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// A photograph-like test image: smooth gradients, a bright disc and texture,
/// luminance over ~5 orders of magnitude, slightly tinted.
fn scene(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let mut l = 0.01 + 2.0 * u * v + 0.2 * (20.0 * u).sin().abs();
        let d2 = (u - 0.7).powi(2) + (v - 0.3).powi(2);
        if d2 < 0.01 {
            l += 500.0;
        }
        l *= 1.0 + 0.1 * hash01(u64::from(y * w + x)) as f32;
        Rgb([l * 1.1, l, l * 0.8])
    })
}

fn assert_close(a: f64, b: f64, tol: f64, what: &str) {
    assert!(
        (a - b).abs() <= tol,
        "{what}: expected {b}, got {a}, difference {} > tolerance {tol}",
        (a - b).abs()
    );
}

#[test]
fn poisson_solution_has_residual_below_1e_9_of_the_source() {
    let (w, h) = (37, 23);
    let mut f: Vec<f64> = (0..w * h).map(|i| hash01(i as u64) - 0.5).collect();
    let mean = f.iter().sum::<f64>() / f.len() as f64;
    f.iter_mut().for_each(|v| *v -= mean);
    let u = solve_poisson_neumann(&f, w, h).unwrap();
    let lu = laplacian_neumann(&u, w, h);
    let res = lu
        .iter()
        .zip(&f)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(res < 1e-9, "max residual {res}");
    // Zero-mean solution.
    assert_close(
        u.iter().sum::<f64>() / u.len() as f64,
        0.0,
        1e-9,
        "mean of u",
    );
}

#[test]
fn poisson_recovers_a_known_field() {
    let (w, h) = (64, 40);
    let truth: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            (x * 0.1).sin() + (y * 0.07).cos() * x * 0.01
        })
        .collect();
    let f = laplacian_neumann(&truth, w, h);
    let u = solve_poisson_neumann(&f, w, h).unwrap();
    let mt = truth.iter().sum::<f64>() / truth.len() as f64;
    let err = u
        .iter()
        .zip(&truth)
        .map(|(a, b)| (a - (b - mt)).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-8, "max error {err}");
}

#[test]
fn fattal_without_attenuation_returns_the_input_log_luminance() {
    let img = scene(96, 64);
    let lum = Plane::luminance_of(&img);
    let h = lum.map(f32::ln);
    let params = FattalParams {
        beta: 1.0,
        ..FattalParams::default()
    };
    let i = compressed_log_luminance(&h, &params).unwrap();
    let mean_h = h.data.iter().map(|&v| f64::from(v)).sum::<f64>() / h.data.len() as f64;
    let err = i
        .data
        .iter()
        .zip(&h.data)
        .map(|(a, b)| (f64::from(*a) - (f64::from(*b) - mean_h)).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-4, "max |I - (H - mean H)| = {err}");
}

#[test]
fn fattal_compresses_the_log_range() {
    let img = scene(96, 64);
    let h = Plane::luminance_of(&img).map(f32::ln);
    let i = compressed_log_luminance(&h, &FattalParams::default()).unwrap();
    let (hl, hh) = h.min_max();
    let (il, ih) = i.min_max();
    assert!(
        ih - il < 0.8 * (hh - hl),
        "range {} vs {}",
        ih - il,
        hh - hl
    );
}

#[test]
fn bilateral_filter_of_a_constant_image_is_constant() {
    let p = Plane::filled(50, 30, 1.25);
    let out = fast_bilateral(&p, 4.0, 0.4);
    for v in out.data {
        assert_close(f64::from(v), 1.25, 1e-5, "filtered constant");
    }
}

#[test]
fn fast_bilateral_matches_the_direct_filter_within_0_05_log_units() {
    // A step edge of 2 log units plus texture; sigma_s = 3 px keeps the grid at full
    // resolution, so only the piecewise-linear range interpolation differs.
    let p = Plane::from_fn(48, 40, |x, y| {
        let base = if x < 24 { 0.0 } else { 2.0 };
        base + 0.3 * (hash01((y * 48 + x) as u64) as f32 - 0.5)
    });
    let fast = fast_bilateral(&p, 3.0, 0.4);
    let direct = bilateral_direct(&p, 3.0, 0.4);
    let err = fast
        .data
        .iter()
        .zip(&direct.data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(err < 0.05, "max difference {err}");
}

#[test]
fn durand_reduces_a_step_to_the_target_base_contrast() {
    // Two flat halves 4 orders of magnitude apart: the detail layer is 0 away from the
    // edge, so the output ratio between halves is the target contrast (5).
    let img = Rgb32FImage::from_fn(200, 40, |x, _| {
        let v = if x < 100 { 1.0 } else { 1.0e4 };
        Rgb([v, v, v])
    });
    let p = DurandParams {
        sigma_spatial_px: Some(4.0),
        ..DurandParams::default()
    };
    let out = Operator::Durand(p).apply(&img).unwrap();
    let dark = f64::from(out.get_pixel(10, 20)[1]);
    let bright = f64::from(out.get_pixel(190, 20)[1]);
    assert_close(bright, 1.0, 0.01, "bright half maps to 1");
    assert_close(bright / dark, 5.0, 0.25, "contrast ratio");
}

#[test]
fn reinhard_global_maps_a_uniform_image_to_key_over_one_plus_key() {
    // log-average = L, so the scaled luminance is the key a, and Eq. 3 gives a / (1 + a).
    let img = Rgb32FImage::from_pixel(8, 8, Rgb([37.0, 37.0, 37.0]));
    let p = ReinhardParams {
        white: Some(f32::INFINITY),
        ..ReinhardParams::default()
    };
    let out = Operator::Reinhard(p).apply(&img).unwrap();
    assert_close(f64::from(out.get_pixel(3, 3)[0]), 0.18 / 1.18, 1e-6, "Ld");
    // Local: all centre-surround differences vanish, the same value results.
    let out = Operator::ReinhardLocal(ReinhardLocalParams::default())
        .apply(&img)
        .unwrap();
    assert_close(
        f64::from(out.get_pixel(3, 3)[0]),
        0.18 / 1.18,
        1e-5,
        "Ld local",
    );
}

#[test]
fn drago_maps_the_brightest_pixel_to_ld_max_over_100() {
    let img = scene(64, 48);
    for ld_max in [100.0f32, 80.0] {
        let p = DragoParams {
            max_display_luminance: ld_max,
            ..DragoParams::default()
        };
        let out = Operator::Drago(p).apply(&img).unwrap();
        let lum = Plane::luminance_of(&out);
        let (_, hi) = lum.min_max();
        assert_close(
            f64::from(hi),
            f64::from(ld_max) / 100.0,
            1e-4,
            "max display",
        );
    }
}

#[test]
fn drago_region_of_interest_on_a_dark_area_brightens_the_image() {
    // HDR VolVis Fig. 4c/4d: a dark region of interest lowers L_wa and raises exposure.
    let img = scene(64, 48);
    let lum_at = |roi| {
        let out = Operator::Drago(DragoParams {
            roi: Some(roi),
            ..DragoParams::default()
        })
        .apply(&img)
        .unwrap();
        f64::from(luminance(out.get_pixel(5, 5).0))
    };
    let dark = lum_at(Roi {
        x_px: 5.0,
        y_px: 5.0,
        radius_px: 4.0,
    });
    let bright = lum_at(Roi {
        x_px: 44.8,
        y_px: 14.4,
        radius_px: 3.0,
    });
    assert!(
        dark > 1.5 * bright,
        "dark-ROI {dark} vs bright-ROI {bright}"
    );
    // A circle outside the image has no lit pixel: a clear error.
    let far = Roi {
        x_px: -100.0,
        y_px: -100.0,
        radius_px: 2.0,
    };
    let err = Operator::Drago(DragoParams {
        roi: Some(far),
        ..DragoParams::default()
    })
    .apply(&img);
    assert!(matches!(err, Err(Error::Parameter(_))));
}

fn global_operators() -> Vec<Operator> {
    vec![
        Operator::Linear(LinearParams {
            exposure_stops: 1.5,
            white: None,
        }),
        Operator::Drago(DragoParams::default()),
        Operator::Drago(DragoParams {
            bias: 0.7,
            saturation: 0.6,
            ..DragoParams::default()
        }),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::Reinhard(ReinhardParams {
            saturation: 0.5,
            ..ReinhardParams::default()
        }),
    ]
}

#[test]
fn global_curves_are_monotonic() {
    let img = scene(64, 48);
    for op in global_operators() {
        let c = op.global_curve(&img).unwrap();
        let limit = c.monotone_limit().min(1e3);
        let mut prev = -1.0;
        for k in 0..2000 {
            let lw = 1e-4 * (limit / 1e-4).powf(k as f64 / 1999.0);
            let ld = c.map_luminance(lw);
            assert!(
                ld > prev,
                "{} not increasing at {lw}: {ld} <= {prev}",
                op.name()
            );
            prev = ld;
        }
    }
}

#[test]
fn drago_is_monotonic_up_to_the_maximum_for_three_orders_above_adaptation() {
    // Slope of Eq. 4 at Lw = Lw_max is positive iff ln(10)/(M+1) > ln(M+1) * 0.8 p / M
    // (p = ln b / ln 0.5): true for M = 1e3 at b = 0.85, false for M = 1e6.
    let curve = |m: f64| GlobalCurve::Drago {
        adaptation: 1.0,
        scaled_max: m,
        bias: 0.85,
        max_display_luminance: 100.0,
        saturation: 1.0,
    };
    assert!(curve(1e3).monotone_limit() > 1e3);
    assert!(curve(1e6).monotone_limit() < 1e6);
}

#[test]
fn inverse_of_each_global_operator_recovers_the_hdr_image() {
    // The scene's disc is ~5e3 times its log-average, where Drago's curve has already
    // peaked: pixels up to the monotone limit are recovered, as HDR VolVis Sec. 4 says.
    let img = scene(64, 48);
    for op in global_operators() {
        let display = op.apply(&img).unwrap();
        let curve = op.global_curve(&img).unwrap();
        let limit = curve.monotone_limit();
        let back = curve.invert(&display);
        let mut checked = 0;
        for ((a, b), l) in back
            .as_raw()
            .chunks(3)
            .zip(img.as_raw().chunks(3))
            .flat_map(|(a, b)| {
                let l = f64::from(luminance([b[0], b[1], b[2]]));
                a.iter().zip(b).map(move |p| (p, l))
            })
        {
            if l >= limit {
                continue;
            }
            checked += 1;
            let rel = f64::from((a - b).abs() / b);
            assert!(rel < 1e-4, "{}: recovered {a}, original {b}", op.name());
        }
        assert!(
            checked > 3 * 64 * 48 * 9 / 10,
            "{}: only {checked} values checked",
            op.name()
        );
    }
}

#[test]
fn inverse_is_refused_for_local_operators() {
    let img = scene(16, 16);
    for op in [
        Operator::ReinhardLocal(ReinhardLocalParams::default()),
        Operator::Durand(DurandParams::default()),
        Operator::Fattal(FattalParams::default()),
    ] {
        assert!(
            matches!(op.global_curve(&img), Err(Error::NotInvertible(_))),
            "{}",
            op.name()
        );
    }
}

fn all_operators() -> Vec<Operator> {
    vec![
        Operator::Linear(LinearParams::default()),
        Operator::Drago(DragoParams::default()),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::ReinhardLocal(ReinhardLocalParams::default()),
        Operator::Durand(DurandParams::default()),
        Operator::Fattal(FattalParams::default()),
    ]
}

#[test]
fn dirty_pixels_never_give_nan_or_a_black_frame_and_black_stays_black() {
    let mut img = scene(64, 48);
    img.put_pixel(1, 1, Rgb([f32::NAN, 1.0, 1.0]));
    img.put_pixel(2, 1, Rgb([-0.5, -1.0, 0.2]));
    img.put_pixel(3, 1, Rgb([f32::INFINITY, f32::INFINITY, f32::INFINITY]));
    img.put_pixel(4, 1, Rgb([f32::NEG_INFINITY, 0.0, 0.0]));
    // A black "volume background" block.
    for y in 30..48 {
        for x in 0..20 {
            img.put_pixel(x, y, Rgb([0.0, 0.0, 0.0]));
        }
    }
    let (_, report) = sanitize(&img);
    assert_eq!(
        report,
        SanitizeReport {
            nan: 1,
            negative: 3,
            positive_infinite: 3
        }
    );
    for op in all_operators() {
        let out = op.apply(&img).unwrap();
        assert!(
            out.as_raw().iter().all(|v| v.is_finite() && *v >= 0.0),
            "{}",
            op.name()
        );
        let mean_lum = Plane::luminance_of(&out).data.iter().sum::<f32>() / (64.0 * 48.0);
        assert!(
            mean_lum > 0.02,
            "{} gives a nearly black frame: {mean_lum}",
            op.name()
        );
        assert_eq!(
            out.get_pixel(5, 40).0,
            [0.0; 3],
            "{}: background not black",
            op.name()
        );
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let img = scene(120, 90);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                all_operators()
                    .iter()
                    .map(|op| op.apply(&img).unwrap())
                    .collect::<Vec<_>>()
            })
    };
    let one = run(1);
    let three = run(3);
    for (op, (a, b)) in all_operators().iter().zip(one.iter().zip(&three)) {
        assert!(
            a.as_raw() == b.as_raw(),
            "{} differs between 1 and 3 threads",
            op.name()
        );
    }
}

#[test]
fn bad_parameters_are_errors() {
    let img = scene(8, 8);
    let bad = [
        Operator::Drago(DragoParams {
            bias: 1.5,
            ..DragoParams::default()
        }),
        Operator::Reinhard(ReinhardParams {
            key: -1.0,
            ..ReinhardParams::default()
        }),
        Operator::ReinhardLocal(ReinhardLocalParams {
            scales: 0,
            ..ReinhardLocalParams::default()
        }),
        Operator::Durand(DurandParams {
            sigma_range: f32::NAN,
            ..DurandParams::default()
        }),
        Operator::Fattal(FattalParams {
            beta: 0.0,
            ..FattalParams::default()
        }),
        Operator::Linear(LinearParams {
            exposure_stops: f32::INFINITY,
            white: None,
        }),
    ];
    for op in bad {
        assert!(matches!(op.apply(&img), Err(Error::Parameter(_))), "{op:?}");
    }
    assert!(matches!(
        Operator::default().apply(&Rgb32FImage::new(0, 5)),
        Err(Error::EmptyImage)
    ));
}

#[test]
fn exposure_series_spans_the_dynamic_range() {
    let img = scene(32, 32);
    let dr = dynamic_range(&img).unwrap();
    let series = ExposureSeries::spanning(&img, 4);
    assert_close(
        f64::from(series.stops(3)),
        dr.ratio.log2(),
        1e-3,
        "last stop",
    );
    let images = exposure_series(&img, &series).unwrap();
    assert_eq!(images.len(), 4);
    // Each image is twice as bright per stop as the first (linear mapping).
    let p0 = f64::from(images[0].get_pixel(3, 3)[1]);
    let p1 = f64::from(images[1].get_pixel(3, 3)[1]);
    assert_close(
        p1 / p0,
        f64::from(series.step_stops).exp2(),
        1e-3,
        "exposure ratio",
    );
}

#[test]
fn dynamic_range_is_max_over_min_nonzero_luminance() {
    let img = Rgb32FImage::from_fn(4, 1, |x, _| {
        let v = [0.0, 0.002, 1.0, 20.0][x as usize];
        Rgb([v, v, v])
    });
    let dr = dynamic_range(&img).unwrap();
    assert_close(dr.ratio, 1.0e4, 1e-2, "ratio");
    assert_close(dr.orders_of_magnitude, 4.0, 1e-5, "orders");
    assert_eq!(dr.zero_pixels, 1);
}

#[test]
fn pseudocolour_maps_min_to_blue_max_to_red_and_adds_a_bar() {
    let img = Rgb32FImage::from_fn(40, 30, |x, _| {
        let v = 10f32.powf(x as f32 / 39.0 * 3.0);
        Rgb([v, v, v])
    });
    let pic = pseudocolour(&img, &PseudocolourParams::default()).unwrap();
    assert!(pic.width() > 40);
    assert_eq!(pic.get_pixel(0, 10).0, [0, 0, 255]);
    assert_eq!(pic.get_pixel(39, 10).0, [255, 0, 0]);
    // The middle decade is green (t = 0.5).
    let mid = pic.get_pixel(19, 10).0;
    assert!(mid[1] > 200 && mid[0] < 60, "{mid:?}");
}

#[test]
fn global_operator_pixels_follow_their_f64_curve_to_1e_5() {
    // `apply` evaluates the global curves per pixel in f32; the reference is the
    // documented f64 curve (`GlobalCurve::map_luminance`) times the colour ratio.
    let img = scene(64, 48);
    for op in global_operators() {
        let curve = op.global_curve(&img).unwrap();
        let s = curve.saturation();
        let out = op.apply(&img).unwrap();
        for (x, y, px) in img.enumerate_pixels() {
            let c = px.0.map(f64::from);
            let l = 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
            let ld = curve.map_luminance(l);
            for k in 0..3 {
                let want = (c[k] / l).powf(f64::from(s)) * ld;
                let got = f64::from(out.get_pixel(x, y).0[k]);
                assert!(
                    (got - want).abs() <= 1e-5 * want.abs().max(1e-3),
                    "{} at ({x},{y}) channel {k}: {got} vs {want}",
                    op.name()
                );
            }
        }
    }
}

#[test]
fn clean_image_matches_sanitize_and_dynamic_range_and_apply() {
    let mut img = scene(40, 30);
    img.put_pixel(1, 1, Rgb([f32::NAN, 1.0, 1.0]));
    img.put_pixel(2, 1, Rgb([-0.5, -1.0, 0.2]));
    img.put_pixel(3, 1, Rgb([f32::INFINITY, 2.0, 1.0]));
    img.put_pixel(0, 0, Rgb([0.0, 0.0, 0.0]));
    let clean = CleanImage::new(&img);
    let (reference, report) = sanitize(&img);
    assert_eq!(clean.report, report);
    assert_eq!(clean.image.as_raw(), reference.as_raw());
    // +Inf became the channel's largest finite value (the 500 cd/m^2 disc, tinted).
    let red_max = img
        .as_raw()
        .iter()
        .step_by(3)
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f32, f32::max);
    assert_eq!(clean.image.get_pixel(3, 1).0[0], red_max);
    assert_eq!(
        clean.luminance.data,
        Plane::luminance_of(&reference).data,
        "luminance is that of the cleaned image"
    );
    let dr = clean.dynamic_range().unwrap();
    assert_eq!(Some(dr), dynamic_range(&img));
    assert_eq!(dr.zero_pixels, 1);
    let mut in_place = img.clone();
    assert_eq!(sanitize_in_place(&mut in_place), report);
    assert_eq!(in_place.as_raw(), reference.as_raw());
    for op in all_operators() {
        assert_eq!(
            op.apply_clean(&clean).unwrap().as_raw(),
            op.apply(&img).unwrap().as_raw(),
            "{}",
            op.name()
        );
    }
}

/// The colour bar names its quantity: text above the bar (the old bar had only decades).
#[test]
fn pseudocolour_bar_names_its_quantity() {
    let img = Rgb32FImage::from_fn(64, 200, |x, _| {
        let v = 10f32.powf(x as f32 / 63.0 * 3.0);
        Rgb([v, v, v])
    });
    let pic = pseudocolour(&img, &PseudocolourParams::default()).unwrap();
    // The bar starts below the title line; above it, in the bar's column, dark glyph pixels.
    let mut dark = 0;
    for y in 0..20 {
        for x in 64..pic.width() {
            dark += usize::from(pic.get_pixel(x, y).0[0] < 100);
        }
    }
    assert!(dark > 20, "no label above the bar ({dark} dark pixels)");
    assert_eq!(PseudocolourParams::default().label, "luminance");
}

/// Without infinities the cleaning pass also gives the luminance statistics: against a
/// value-by-value count and the luminance plane's own range, on widths that leave every
/// remainder of the four-pixel lanes (1..=5 pixels past a multiple of 4), with NaN,
/// negatives, -Inf, zeros and black pixels spread by a hash.
#[test]
fn one_pass_statistics_equal_a_value_by_value_count() {
    for w in [1u32, 2, 3, 5, 7, 13, 37] {
        let h = 9u32;
        let img = Rgb32FImage::from_fn(w, h, |x, y| {
            let i = u64::from(y * w + x);
            let pick = |c: u64| {
                let u = hash01(3 * i + c);
                match (u * 16.0) as u32 {
                    0 => f32::NAN,
                    1 => -0.25,
                    2 => f32::NEG_INFINITY,
                    3 | 4 => 0.0,
                    _ => (10.0f64.powf(6.0 * u - 3.0)) as f32,
                }
            };
            Rgb([pick(0), pick(1), pick(2)])
        });
        let clean = CleanImage::new(&img);
        let (mut nan, mut neg) = (0u64, 0u64);
        let mut cleaned = img.clone();
        for v in cleaned.iter_mut() {
            if v.is_nan() {
                nan += 1;
                *v = 0.0;
            } else if *v < 0.0 {
                neg += 1;
                *v = 0.0;
            }
        }
        assert_eq!(
            clean.report,
            SanitizeReport {
                nan,
                negative: neg,
                positive_infinite: 0
            },
            "width {w}"
        );
        assert_eq!(clean.image.as_raw(), cleaned.as_raw(), "width {w}");
        let lum: Vec<f32> = cleaned.pixels().map(|p| luminance(p.0)).collect();
        assert_eq!(clean.luminance.data, lum, "width {w}");
        let zeros = lum.iter().filter(|&&v| v <= 0.0).count() as u64;
        let positive: Vec<f32> = lum.iter().copied().filter(|&v| v > 0.0).collect();
        match clean.dynamic_range() {
            Some(dr) => {
                assert_eq!(dr.zero_pixels, zeros, "width {w}");
                assert_eq!(
                    dr.min_positive,
                    positive.iter().copied().fold(f32::INFINITY, f32::min)
                );
                assert_eq!(dr.max, positive.iter().copied().fold(0.0, f32::max));
            }
            None => assert!(positive.is_empty(), "width {w}"),
        }
    }
}

/// Straight to 8-bit codes is the float display image's codes, byte for byte: every
/// operator (the global ones take the one-pass path), saturation 1 and not, an image with
/// dirty pixels and a black block, and an all-black image.
#[test]
fn srgb8_output_equals_the_display_images_codes() {
    let mut img = scene(61, 23);
    img.put_pixel(1, 1, Rgb([f32::NAN, 1.0, 1.0]));
    img.put_pixel(2, 1, Rgb([-0.5, -1.0, 0.2]));
    img.put_pixel(3, 1, Rgb([f32::INFINITY, 2.0, 1.0]));
    for y in 10..20 {
        for x in 0..9 {
            img.put_pixel(x, y, Rgb([0.0, 0.0, 0.0]));
        }
    }
    let black = Rgb32FImage::new(9, 4);
    let mut ops = all_operators();
    ops.push(Operator::Drago(DragoParams {
        saturation: 0.6,
        exposure_stops: 1.5,
        ..DragoParams::default()
    }));
    ops.push(Operator::Reinhard(ReinhardParams {
        saturation: 1.3,
        white: Some(4.0),
        ..ReinhardParams::default()
    }));
    for image in [&img, &black] {
        let clean = CleanImage::new(image);
        for op in &ops {
            let display = op.apply_clean(&clean).unwrap();
            assert_eq!(
                op.apply_clean_srgb8(&clean).unwrap(),
                io::display_to_srgb8(&display),
                "{}",
                op.name()
            );
        }
    }
}
