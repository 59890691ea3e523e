//! Issue 19 item 15: the local operators' colour and low-frequency behaviour, checked
//! against properties that hold independently of the implementation.
//!
//! - Gamut: every output channel of a local operator lies in [0, 1] before quantisation.
//! - Hue and luminance: with saturation 1 the chroma direction `C - Y` of every output
//!   pixel is the input's, and the output luminance is what the operator gives the
//!   achromatic image of the same luminance (the luminance path sees luminance only),
//!   capped at 1.
//! - No low-frequency glow (Fattal): the operator commutes with mirroring the image, and
//!   the dark field on either side of a bright bar comes out equally bright.
//! - No washed-out base (Durand): a handful of isolated near-black noise pixels (what the
//!   dirty-input rule leaves of a photograph's negative values) does not change the picture.

use blueshift_tonemap::plane::fit_to_display;
use blueshift_tonemap::*;
use image::{Rgb, Rgb32FImage};

/// Counter-based hash to [0, 1): deterministic test inputs without a RNG crate.
fn hash01(i: u64) -> f32 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64) as f32
}

/// Saturated colours over four orders of magnitude: a dim room of coloured tiles with a
/// bright window of coloured panes (the Desk photograph in miniature).
fn colourful(w: u32, h: u32) -> Rgb32FImage {
    const HUES: [[f32; 3]; 6] = [
        [1.0, 0.05, 0.02],
        [0.05, 1.0, 0.1],
        [0.02, 0.1, 1.0],
        [1.0, 0.7, 0.05],
        [0.9, 0.05, 0.8],
        [0.05, 0.8, 0.9],
    ];
    Rgb32FImage::from_fn(w, h, |x, y| {
        let tile = ((x / 6) + 7 * (y / 6)) as usize;
        let c = HUES[tile % HUES.len()];
        let window = x > w / 3 && x < 2 * w / 3 && y < h / 2;
        let level = if window {
            300.0
        } else {
            0.05 + 0.5 * x as f32 / w as f32
        };
        let l = level * (0.7 + 0.6 * hash01(u64::from(y * w + x)));
        Rgb([c[0] * l, c[1] * l, c[2] * l])
    })
}

fn grey_of(img: &Rgb32FImage) -> Rgb32FImage {
    Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
        let p = img.get_pixel(x, y).0;
        let l = luminance(p);
        Rgb([l, l, l])
    })
}

fn local_operators(saturation: f32) -> Vec<Operator> {
    vec![
        Operator::Durand(DurandParams {
            saturation,
            ..DurandParams::default()
        }),
        Operator::Fattal(FattalParams {
            saturation,
            ..FattalParams::default()
        }),
        Operator::ReinhardLocal(ReinhardLocalParams {
            saturation,
            ..ReinhardLocalParams::default()
        }),
    ]
}

#[test]
fn local_operators_keep_every_channel_in_the_display_range() {
    let img = colourful(96, 64);
    for s in [1.0, 0.5, 1.5] {
        for op in local_operators(s) {
            let out = op.apply(&img).unwrap();
            let (lo, hi) = out
                .as_raw()
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            assert!(
                lo >= 0.0 && hi <= 1.0,
                "{} (s = {s}): channels span [{lo}, {hi}], outside [0, 1]",
                op.name()
            );
        }
    }
}

#[test]
fn local_operators_keep_hue_and_luminance_when_they_bring_colours_into_range() {
    let img = colourful(96, 64);
    let grey = grey_of(&img);
    for op in local_operators(1.0) {
        let out = op.apply(&img).unwrap();
        let out_grey = op.apply(&grey).unwrap();
        let mut fitted = 0usize;
        for (x, y, p) in out.enumerate_pixels() {
            let c_in = img.get_pixel(x, y).0;
            let c_out = p.0;
            let y_in = luminance(c_in);
            let y_out = luminance(c_out);
            // The luminance path sees only luminance: the grey image's output luminance
            // is the operator's L_out (grey is in the display cube whenever L_out <= 1).
            let l_target = out_grey.get_pixel(x, y).0[1].min(1.0);
            assert!(
                (y_out - l_target).abs() <= 2e-4 + 1e-3 * l_target,
                "{}: pixel ({x}, {y}) luminance {y_out}, operator's luminance {l_target}",
                op.name()
            );
            let any_over = c_in.iter().any(|&c| c / y_in * l_target > 1.0);
            if l_target >= 1.0 - 1e-4 {
                continue; // white: no chroma can be shown
            }
            fitted += usize::from(any_over);
            // Chroma direction: C - Y, normalised.
            let chroma = |c: [f32; 3], l: f32| {
                let d = [c[0] - l, c[1] - l, c[2] - l];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                (d, n)
            };
            let (di, ni) = chroma(c_in, y_in);
            let (dout, nout) = chroma(c_out, y_out);
            if ni <= 1e-6 * y_in || nout <= 1e-4 {
                continue; // achromatic: no direction to compare
            }
            let cos = (di[0] * dout[0] + di[1] * dout[1] + di[2] * dout[2]) / (ni * nout);
            assert!(
                cos > 0.9999,
                "{}: pixel ({x}, {y}) hue turned: input {c_in:?}, output {c_out:?}, cos {cos}",
                op.name()
            );
        }
        assert!(
            fitted > 100,
            "{}: only {fitted} pixels needed fitting, the test does not exercise the gamut step",
            op.name()
        );
    }
}

#[test]
fn fit_to_display_is_the_identity_inside_and_desaturates_at_constant_luminance_outside() {
    for c in [
        [0.2, 0.5, 0.9],
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [1.0, 0.0, 0.3],
    ] {
        assert_eq!(fit_to_display(c), c);
    }
    // Pure-ish red whose red channel is far above 1 at a luminance of 0.5.
    let c = [2.0f32, 0.1, 0.05];
    let l = luminance(c);
    let scale = 0.5 / l;
    let c = c.map(|v| v * scale);
    let f = fit_to_display(c);
    assert!(f.iter().all(|v| (0.0..=1.0).contains(v)), "{f:?}");
    assert!((luminance(f) - 0.5).abs() < 1e-6, "{f:?}");
    assert!(
        (f[0] - 1.0).abs() < 1e-6,
        "the smallest desaturation that fits: {f:?}"
    );
    // Same direction of C - Y, shorter.
    let t = (f[1] - 0.5) / (c[1] - 0.5);
    for k in 0..3 {
        assert!(
            (f[k] - 0.5 - t * (c[k] - 0.5)).abs() < 1e-6,
            "{f:?} vs {c:?}"
        );
    }
    assert!(t > 0.0 && t < 1.0);
    assert_eq!(fit_to_display([3.0, 2.0, 1.5]), [1.0; 3]);
    assert_eq!(fit_to_display([f32::NAN, 2.0, 0.0]), [0.0; 3]);
}

/// A dark textured field (luminance about 0.01) with a bright vertical bar (1e3) in the
/// middle: mirror-symmetric about the vertical centre line.
fn bar_scene(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| {
        let xm = x.min(w - 1 - x); // mirror-symmetric texture
        let l = if (w / 2 - 8..w / 2 + 8).contains(&x) {
            1.0e3
        } else {
            0.01 * (1.0 + 0.5 * hash01(u64::from(y * w + xm)))
        };
        Rgb([l, l, l])
    })
}

fn mean_luminance(img: &Rgb32FImage, xs: std::ops::Range<u32>) -> f64 {
    let mut s = 0.0f64;
    let mut n = 0u32;
    for y in 0..img.height() {
        for x in xs.clone() {
            s += f64::from(luminance(img.get_pixel(x, y).0));
            n += 1;
        }
    }
    s / f64::from(n)
}

#[test]
fn fattal_does_not_lift_the_dark_field_on_one_side_of_a_bright_bar() {
    let (w, h) = (256u32, 128u32);
    let img = bar_scene(w, h);
    let out = Operator::Fattal(FattalParams::default())
        .apply(&img)
        .unwrap();
    // The same input left and right of the bar, far from it (a quarter of the width).
    let left = mean_luminance(&out, 8..56);
    let right = mean_luminance(&out, w - 56..w - 8);
    assert!(
        (left - right).abs() <= 0.01 * left.max(right),
        "dark field left of the bar {left}, right of it {right}: a one-sided glow"
    );
}

#[test]
fn fattal_commutes_with_mirroring() {
    // Sides that halve evenly down the pyramid, so every level is mirror-symmetric.
    let (w, h) = (256u32, 128u32);
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let disc = (u - 0.3).powi(2) + (v - 0.4).powi(2) < 0.01;
        let l = if disc { 500.0 } else { 0.02 + 2.0 * u * v }
            * (0.8 + 0.4 * hash01(u64::from(y * w + x)));
        Rgb([l, l, l])
    });
    let mirror = |im: &Rgb32FImage| image::imageops::flip_horizontal(im);
    let op = Operator::Fattal(FattalParams {
        saturation: 1.0,
        ..FattalParams::default()
    });
    let a = mirror(&op.apply(&img).unwrap());
    let b = op.apply(&mirror(&img)).unwrap();
    let err = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(p, q)| (p - q).abs())
        .fold(0.0f32, f32::max);
    assert!(
        err < 2e-3,
        "mirror(fattal(img)) and fattal(mirror(img)) differ by {err}"
    );
}

#[test]
fn durand_is_not_washed_out_by_a_few_isolated_noise_pixels() {
    // Dark textured field at ~0.1 with a bright window at ~100; then 0.05 % of the
    // pixels set to 1e-7 (a photograph's cleaned noise: one channel left, far below
    // the rest). The picture away from those pixels must stay the same.
    let (w, h) = (160u32, 120u32);
    let clean = Rgb32FImage::from_fn(w, h, |x, y| {
        let window = x > 100 && y < 60;
        let base = if window { 100.0 } else { 0.1 };
        let l = base * (0.6 + 0.8 * hash01(u64::from(y * w + x)));
        Rgb([l, l, l])
    });
    let mut noisy = clean.clone();
    let mut hit = vec![false; (w * h) as usize];
    for k in 0..10u64 {
        let i = (hash01(1_000_000 + k) * (w * h) as f32) as u32 % (w * h);
        hit[i as usize] = true;
        noisy.put_pixel(i % w, i / w, Rgb([1e-7 / 0.2126, 0.0, 0.0]));
    }
    let op = Operator::Durand(DurandParams::default());
    let a = op.apply(&clean).unwrap();
    let b = op.apply(&noisy).unwrap();
    let mut worst = 0.0f32;
    for (i, (pa, pb)) in a.pixels().zip(b.pixels()).enumerate() {
        if hit[i] {
            continue;
        }
        let (la, lb) = (luminance(pa.0), luminance(pb.0));
        worst = worst.max((lb / la.max(1e-6)).ln().abs());
    }
    assert!(
        worst < 0.05,
        "ten noise pixels out of {} changed the picture by up to {:.1} % in luminance",
        w * h,
        100.0 * worst.exp_m1()
    );
}
