//! Transfer-function evaluation, alpha_g, HSV interpolation, log data axis, lookup tables and
//! max-opacity queries.

mod common;
use common::assert_close;

use blueshift_tfedit::color::{hsv_to_rgb, rgb_to_hsv};
use blueshift_tfedit::{
    ColorKnot, ColorSpace, DataAxis, Error, MAX_LUT_ENTRIES, OpacityKnot, TransferFunction,
};
use proptest::prelude::*;

fn ck(x: f64, rgb: [f32; 3]) -> ColorKnot {
    ColorKnot { x, rgb }
}

#[test]
fn alpha_g_multiplies_every_opacity() {
    // HDR VolVis section 3: alpha_g multiplies the opacity returned by the transfer function.
    let base = TransferFunction::new(
        [0.0, 1.0],
        vec![ck(0.0, [1.0, 0.5, 0.0])],
        vec![
            OpacityKnot::new(0.0, 0.1),
            OpacityKnot::new(0.3, 0.9),
            OpacityKnot::new(1.0, 0.5),
        ],
    )
    .unwrap();
    let scaled = base.clone().with_alpha_g(0.005).unwrap();
    for i in 0..=100 {
        let v = f64::from(i) / 100.0;
        let expected = f64::from(base.eval(v)[3]) * 0.005;
        assert_close(
            f64::from(scaled.eval(v)[3]),
            expected,
            1e-9,
            "alpha_g * opacity",
        );
        assert_eq!(scaled.eval(v)[..3], base.eval(v)[..3]);
    }
    assert_close(
        f64::from(scaled.global_max_opacity()),
        0.9 * 0.005,
        1e-9,
        "global max",
    );
}

#[test]
fn hsv_interpolation_goes_the_short_way_round_the_hue_circle() {
    // Red (hue 0) to a purple of hue 0.8: the short arc passes through hue 0.9 (magenta),
    // the long one would pass through green and cyan (hue 0.4).
    let purple = hsv_to_rgb([0.8, 1.0, 1.0]).map(|c| c as f32);
    let tf = TransferFunction::new(
        [0.0, 1.0],
        vec![ck(0.0, [1.0, 0.0, 0.0]), ck(1.0, purple)],
        vec![OpacityKnot::new(0.0, 1.0)],
    )
    .unwrap()
    .with_color_space(ColorSpace::Hsv);
    let mid = tf.color(0.5).map(f64::from);
    assert_close(rgb_to_hsv(mid)[0], 0.9, 1e-6, "hue half way");
    for i in 0..=50 {
        let h = rgb_to_hsv(tf.color(f64::from(i) / 50.0).map(f64::from))[0];
        assert!(!(0.01..0.79).contains(&h), "hue {h} is on the long arc");
    }
    // The same knots in RGB pass through (0.9, 0, 0.5): a different colour, so the space matters.
    let rgb = tf.clone().with_color_space(ColorSpace::Rgb).color(0.5);
    assert!(
        (rgb[0] - 0.9).abs() < 1e-6 && (rgb[2] - 0.5).abs() < 1e-6,
        "{rgb:?}"
    );
}

#[test]
fn hsv_interpolation_keeps_full_saturation_and_value_between_saturated_knots() {
    // Blue (hue 2/3) to yellow (hue 1/6): half way in HSV is hue 5/12 at full saturation
    // and value (a saturated green-cyan), where RGB gives grey (0.5, 0.5, 0.5).
    let tf = TransferFunction::new(
        [0.0, 1.0],
        vec![ck(0.0, [0.0, 0.0, 1.0]), ck(1.0, [1.0, 1.0, 0.0])],
        vec![OpacityKnot::new(0.0, 1.0)],
    )
    .unwrap()
    .with_color_space(ColorSpace::Hsv);
    let hsv = rgb_to_hsv(tf.color(0.5).map(f64::from));
    assert_close(hsv[0], 5.0 / 12.0, 1e-6, "hue");
    assert_close(hsv[1], 1.0, 1e-6, "saturation");
    assert_close(hsv[2], 1.0, 1e-6, "value");
}

#[test]
fn log_data_axis_interpolates_in_log10_of_the_value() {
    // Knots at 1, 10, 100 with opacities 0, 1, 0: on a log axis sqrt(10) is half way
    // between 1 and 10, so its opacity is 0.5; 10^1.75 is three quarters of the way from
    // 10 (opacity 1) to 100 (opacity 0), so 0.25.
    let tf = TransferFunction::new(
        [1.0, 100.0],
        vec![ck(1.0, [0.0; 3]), ck(100.0, [1.0; 3])],
        vec![
            OpacityKnot::new(1.0, 0.0),
            OpacityKnot::new(10.0, 1.0),
            OpacityKnot::new(100.0, 0.0),
        ],
    )
    .unwrap()
    .with_data_axis(DataAxis::Log)
    .unwrap();
    assert_close(
        f64::from(tf.opacity(10f64.sqrt())),
        0.5,
        1e-6,
        "opacity at sqrt(10)",
    );
    assert_close(
        f64::from(tf.opacity(10f64.powf(1.75))),
        0.25,
        1e-6,
        "opacity at 10^1.75",
    );
    assert_close(
        f64::from(tf.color(10.0)[0]),
        0.5,
        1e-6,
        "colour half way in log",
    );
    assert_close(tf.normalized(10.0), 0.5, 1e-12, "normalised position of 10");
    assert_close(tf.value_at_normalized(0.5), 10.0, 1e-9, "value at 0.5");
}

#[test]
fn log_data_axis_refuses_non_positive_domains_and_knots() {
    let tf = TransferFunction::new(
        [0.0, 100.0],
        vec![ck(0.0, [0.0; 3])],
        vec![OpacityKnot::new(0.0, 0.0)],
    )
    .unwrap();
    let err = tf.with_data_axis(DataAxis::Log).unwrap_err();
    assert!(
        matches!(err, Error::Invalid(_)) && err.to_string().contains("positive"),
        "{err}"
    );
}

#[test]
fn bad_knots_get_errors_naming_the_entry() {
    let c = vec![ck(0.0, [0.0; 3])];
    let e = TransferFunction::new([0.0, 1.0], c.clone(), vec![]).unwrap_err();
    assert!(e.to_string().contains("no opacity knots"), "{e}");
    let e =
        TransferFunction::new([0.0, 1.0], vec![], vec![OpacityKnot::new(0.0, 0.0)]).unwrap_err();
    assert!(e.to_string().contains("no colour knots"), "{e}");
    let e = TransferFunction::new(
        [0.0, 1.0],
        c.clone(),
        vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(0.5, 1.5)],
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("opacity knot 1") && e.to_string().contains("1.5"),
        "{e}"
    );
    let e = TransferFunction::new(
        [0.0, 1.0],
        c.clone(),
        vec![
            OpacityKnot::new(0.6, 0.0),
            OpacityKnot::new(0.5, 0.2),
            OpacityKnot::new(0.4, 0.2),
        ],
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("opacity knot 1") && e.to_string().contains("sorted"),
        "{e}"
    );
    let e = TransferFunction::new(
        [0.0, 1.0],
        vec![ck(f64::NAN, [0.0; 3])],
        vec![OpacityKnot::new(0.0, 0.0)],
    )
    .unwrap_err();
    assert!(e.to_string().contains("colour knot 0"), "{e}");
    let e =
        TransferFunction::new([1.0, 1.0], c.clone(), vec![OpacityKnot::new(0.0, 0.0)]).unwrap_err();
    assert!(e.to_string().contains("domain"), "{e}");
    let e = TransferFunction::new([0.0, f64::INFINITY], c, vec![OpacityKnot::new(0.0, 0.0)])
        .unwrap_err();
    assert!(e.to_string().contains("domain"), "{e}");
}

#[test]
fn nan_data_is_transparent_and_takes_the_nan_colour() {
    let tf = blueshift_tfedit::builtin("grey")
        .unwrap()
        .with_nan_color([1.0, 0.0, 1.0])
        .unwrap();
    assert_eq!(tf.eval(f64::NAN), [1.0, 0.0, 1.0, 0.0]);
}

#[test]
fn lut_entry_i_is_the_function_at_min_plus_i_step() {
    let tf = blueshift_tfedit::builtin_over("cool-warm", [-5.0, 20.0])
        .unwrap()
        .with_alpha_g(0.25)
        .unwrap();
    for n in [256usize, 65_536] {
        let lut = tf.lut(n).unwrap();
        assert_eq!(lut.len(), n);
        for i in (0..n).step_by(n / 64).chain([n - 1]) {
            let v = -5.0 + i as f64 * 25.0 / (n - 1) as f64;
            let e = lut.get(i).unwrap();
            let f = tf.eval(v);
            for c in 0..4 {
                assert_close(f64::from(e[c]), f64::from(f[c]), 1e-6, "lut entry");
            }
        }
        assert_eq!(lut.get(0).unwrap(), tf.eval(-5.0));
        assert_eq!(lut.get(n - 1).unwrap(), tf.eval(20.0));
    }
}

#[test]
fn lut_lengths_outside_2_to_2_pow_24_are_refused() {
    let tf = blueshift_tfedit::builtin("grey").unwrap();
    for n in [0, 1, MAX_LUT_ENTRIES + 1, usize::MAX] {
        let e = tf.lut(n).unwrap_err();
        assert!(matches!(e, Error::Parameter(_)), "{e}");
    }
}

/// A random transfer function: 1-12 opacity knots (some repeated positions), some with
/// VTK midpoint/sharpness shaping, on a linear or log axis.
fn arb_tf() -> impl Strategy<Value = TransferFunction> {
    (
        prop::collection::vec(
            (
                0.0f64..1.0,
                0.0f32..=1.0,
                0.05f32..0.95,
                prop::sample::select(vec![0.0f32, 0.0, 0.3, 1.0]),
            ),
            1..12,
        ),
        any::<bool>(),
        0.0f32..=1.0,
    )
        .prop_map(|(mut knots, log, alpha_g)| {
            knots.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (domain, map): ([f64; 2], fn(f64) -> f64) = if log {
                ([1e-3, 1e3], |t| 10f64.powf(-3.0 + 6.0 * t))
            } else {
                ([-2.0, 3.0], |t| -2.0 + 5.0 * t)
            };
            let opacity = knots
                .iter()
                .map(|&(t, a, m, s)| OpacityKnot {
                    x: map(t),
                    alpha: a,
                    midpoint: m,
                    sharpness: s,
                })
                .collect();
            TransferFunction::new(
                domain,
                vec![ColorKnot {
                    x: domain[0],
                    rgb: [1.0; 3],
                }],
                opacity,
            )
            .unwrap()
            .with_data_axis(if log { DataAxis::Log } else { DataAxis::Linear })
            .unwrap()
            .with_alpha_g(alpha_g)
            .unwrap()
        })
}

proptest! {
    /// MDWT section 4.3: a majorant must bound the opacity everywhere in the macrocell's
    /// value range. Checked against 2,001 dense samples (bit for bit: `>=`), and for
    /// straight segments the bound is tight to within one sample spacing times the
    /// steepest slope.
    #[test]
    fn max_opacity_bounds_dense_sampling(tf in arb_tf(), a in 0.0f64..1.0, b in 0.0f64..1.0) {
        let (lo, hi) = (a.min(b), a.max(b));
        let lo_v = tf.value_at_normalized(lo);
        let hi_v = tf.value_at_normalized(hi);
        let m = tf.max_opacity(lo_v..=hi_v);
        let mut dense = 0f32;
        let n = 2000;
        for i in 0..=n {
            let v = lo_v + (hi_v - lo_v) * f64::from(i) / f64::from(n);
            let o = tf.eval(v)[3];
            prop_assert!(o <= m, "eval({v}) = {o} > max_opacity = {m}");
            dense = dense.max(o);
        }
        // Also at the knots themselves and just beside them.
        for k in tf.opacity_knots() {
            for v in [k.x, k.x.next_up(), k.x.next_down()] {
                if (lo_v..=hi_v).contains(&v) {
                    let o = tf.eval(v)[3];
                    prop_assert!(o <= m, "eval(knot {v}) = {o} > {m}");
                    dense = dense.max(o);
                }
            }
        }
        let straight = tf.opacity_knots().iter().all(|k| k.sharpness < 0.01 || k.sharpness > 0.99);
        let has_step = tf.opacity_knots().iter().any(|k| k.sharpness > 0.99);
        if straight && !has_step && hi - lo > 0.0 {
            // Slope bound in opacity per normalised unit: the steepest segment.
            let ks = tf.opacity_knots();
            let mut slope = 0.0f64;
            for w in ks.windows(2) {
                let dt = tf.normalized(w[1].x) - tf.normalized(w[0].x);
                if dt > 0.0 {
                    // midpoint remapping steepens a straight segment by up to 0.5 / min(m, 1 - m).
                    let mshape = f64::from(w[0].midpoint.min(1.0 - w[0].midpoint));
                    slope = slope.max(f64::from((w[1].alpha - w[0].alpha).abs()) / dt * 0.5 / mshape);
                }
            }
            let gap = slope * (hi - lo) / f64::from(n) * f64::from(tf.alpha_g()) + 1e-6;
            prop_assert!(f64::from(m - dense) <= gap, "max_opacity {m} exceeds dense max {dense} by more than {gap}");
        }
    }
}

proptest! {
    /// The table walks the knots instead of searching them; every entry must still be
    /// exactly `eval` at `min + i (max - min) / (N - 1)`.
    #[test]
    fn lut_entries_are_eval_bit_for_bit(tf in arb_tf(), n in 2usize..3000) {
        let lut = tf.lut(n).unwrap();
        let [lo, hi] = tf.domain();
        for i in 0..n {
            let v = if i + 1 == n { hi } else { lo + i as f64 * ((hi - lo) / (n - 1) as f64) };
            prop_assert_eq!(lut.get(i).unwrap(), tf.eval(v), "entry {} of {}", i, n);
        }
    }
}

#[test]
fn lut_is_identical_on_one_and_four_threads() {
    let tf = blueshift_tfedit::builtin_over("cool-warm", [-1.0, 7.0])
        .unwrap()
        .with_alpha_g(0.3)
        .unwrap();
    let build = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| tf.lut(100_003).unwrap())
    };
    let (one, four) = (build(1), build(4));
    assert!(
        one.as_rgba()
            .iter()
            .zip(four.as_rgba())
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
}

/// A domain whose width overflows ([-1e308, 1e308]: lookups would divide by infinity) or is
/// subnormal ([0, 5e-324]: a zero tick step) is refused with the domain named.
#[test]
fn domains_of_infinite_or_subnormal_width_are_refused() {
    for d in [[-1e308, 1e308], [0.0, 5e-324]] {
        let e = TransferFunction::new(
            d,
            vec![ck(d[0], [0.0; 3])],
            vec![OpacityKnot::new(d[0], 0.0)],
        )
        .unwrap_err();
        assert!(
            matches!(e, Error::Invalid(_)) && e.to_string().contains("width"),
            "{e}"
        );
    }
}
