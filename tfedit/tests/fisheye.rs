//! Focus+context axes: HDR VolVis Eq. 2 and Fig. 6/7.

mod common;
use common::assert_close;

use blueshift_tfedit::{Error, Fisheye, FocusRegion, ValueAxis};
use proptest::prelude::*;

fn region(center: f64, width: f64, magnification: f64, transition: f64) -> FocusRegion {
    FocusRegion { center, width, magnification, transition }
}

#[test]
fn single_focus_m_min_matches_eq2_solved_by_hand() {
    // Eq. 2 with R_c of width w, two transitions of width tau (M_tr averaging
    // (M_c + M_min) / 2) and the rest at M_min:
    //   M_min (1 - w - 2 tau) + M_c w + (M_c + M_min) tau = 1
    //   => M_min = (1 - M_c (w + tau)) / (1 - w - tau).
    let (w, tau, mc) = (0.1, 0.05, 4.0);
    let f = Fisheye::new(vec![region(0.4, w, mc, tau)]).unwrap();
    let expected = (1.0 - mc * (w + tau)) / (1.0 - w - tau);
    assert_close(f.m_min(), expected, 1e-12, "M_min");
    assert_close(f.total_width(), 1.0, 1e-12, "Eq. 2 left-hand side");
}

#[test]
fn eq2_integral_holds_by_independent_quadrature() {
    // Integrate the magnification curve M(t) (Fig. 6b) with a fine midpoint rule: the
    // window must be filled exactly once.
    let f = Fisheye::new(vec![
        region(0.15, 0.1, 3.0, 0.05),
        region(0.6, 0.05, 4.0, 0.02),
        region(0.98, 0.1, 2.0, 0.03), // clipped at 1
    ])
    .unwrap();
    let n = 200_000;
    let integral: f64 = (0..n).map(|i| f.magnification((f64::from(i) + 0.5) / f64::from(n))).sum::<f64>() / f64::from(n);
    assert_close(integral, 1.0, 1e-6, "∫ M(t) dt over [0, 1]");
    assert!(f.m_min() > 0.0 && f.m_min() < 1.0);
}

#[test]
fn impossible_or_overlapping_focus_settings_are_refused() {
    // M_c w = 2 > 1: the focus alone is wider than the window, M_min would be negative.
    let e = Fisheye::new(vec![region(0.5, 0.2, 10.0, 0.0)]).unwrap_err();
    assert!(matches!(e, Error::Parameter(_)) && e.to_string().contains("M_min"), "{e}");
    // Exactly filling the window leaves M_min = 0, also refused.
    let e = Fisheye::new(vec![region(0.5, 0.25, 4.0, 0.0)]).unwrap_err();
    assert!(e.to_string().contains("M_min"), "{e}");
    let e = Fisheye::new(vec![region(0.3, 0.1, 2.0, 0.05), region(0.45, 0.1, 2.0, 0.05)]).unwrap_err();
    assert!(e.to_string().contains("overlap"), "{e}");
    for bad in [region(0.5, 0.1, 1.0, 0.0), region(1.5, 0.1, 2.0, 0.0), region(0.5, 0.0, 2.0, 0.0), region(0.5, 0.1, 2.0, -0.1), region(0.5, f64::NAN, 2.0, 0.0)] {
        assert!(Fisheye::new(vec![bad]).is_err(), "{bad:?} accepted");
    }
}

#[test]
fn no_focus_is_the_linear_axis() {
    let f = Fisheye::new(vec![]).unwrap();
    assert!(f.is_linear());
    for i in 0..=10 {
        let t = f64::from(i) / 10.0;
        assert_eq!(f.forward(t), t);
        assert_eq!(f.inverse(t), t);
    }
}

#[test]
fn log_value_axis_maps_floor_to_0_one_to_1_and_is_invertible() {
    let a = ValueAxis::log(1e-4).unwrap();
    assert_close(a.forward(1e-4), 0.0, 1e-12, "floor");
    assert_close(a.forward(1.0), 1.0, 1e-12, "one");
    assert_close(a.forward(1e-2), 0.5, 1e-12, "geometric middle");
    assert_eq!(a.forward(1e-9), 0.0, "below the floor sits at the bottom");
    for y in [0.0, 0.1, 0.37, 0.9, 1.0] {
        assert_close(a.forward(a.inverse(y)), y, 1e-12, "round trip");
    }
    assert!(ValueAxis::log(0.0).is_err() && ValueAxis::log(1.0).is_err());
    assert_close(ValueAxis::Linear.forward(0.3), 0.3, 0.0, "linear");
}

/// 1 to 3 non-overlapping focus regions with a feasible total magnification.
fn arb_fisheye() -> impl Strategy<Value = Fisheye> {
    prop::collection::vec((0.0f64..1.0, 0.005f64..0.1, 1.1f64..6.0, 0.0f64..0.05), 1..4)
        .prop_filter_map("overlapping or infeasible", |rs| {
            Fisheye::new(rs.into_iter().map(|(c, w, m, t)| region(c, w, m, t)).collect()).ok()
        })
}

proptest! {
    #[test]
    fn fisheye_sends_0_1_onto_0_1_monotonically(f in arb_fisheye()) {
        prop_assert_eq!(f.forward(0.0), 0.0);
        prop_assert!((f.forward(1.0) - 1.0).abs() < 1e-12);
        let mut prev = f.forward(0.0);
        for i in 1..=4000 {
            let x = f.forward(f64::from(i) / 4000.0);
            prop_assert!(x > prev, "not strictly increasing at {}", i);
            prev = x;
        }
    }

    #[test]
    fn fisheye_magnifies_each_focus_by_m_c(f in arb_fisheye(), a in 0.0f64..1.0, b in 0.0f64..1.0) {
        for r in f.regions() {
            let lo = (r.center - 0.5 * r.width).max(0.0);
            let hi = (r.center + 0.5 * r.width).min(1.0);
            let (t1, t2) = (lo + (hi - lo) * a.min(b), lo + (hi - lo) * a.max(b));
            if t2 - t1 > 1e-6 {
                let slope = (f.forward(t2) - f.forward(t1)) / (t2 - t1);
                prop_assert!((slope - r.magnification).abs() < 1e-6 * r.magnification,
                    "slope {} in focus, M_c {}", slope, r.magnification);
            }
        }
        // Outside every region and transition the slope is M_min.
        let t = a;
        let inside = f.regions().iter().any(|r| (t - r.center).abs() < 0.5 * r.width + r.transition + 1e-3);
        if !inside && t > 1e-3 && t < 1.0 - 1e-3 {
            let h = 1e-4;
            let slope = (f.forward(t + h) - f.forward(t - h)) / (2.0 * h);
            let near = f.regions().iter().any(|r| (t - r.center).abs() < 0.5 * r.width + r.transition + h);
            if !near {
                prop_assert!((slope - f.m_min()).abs() < 1e-6, "context slope {} vs M_min {}", slope, f.m_min());
            }
        }
    }

    #[test]
    fn fisheye_inverse_is_exact(f in arb_fisheye(), t in 0.0f64..=1.0, x in 0.0f64..=1.0) {
        prop_assert!((f.inverse(f.forward(t)) - t).abs() < 1e-12, "t {} -> {} -> {}", t, f.forward(t), f.inverse(f.forward(t)));
        prop_assert!((f.forward(f.inverse(x)) - x).abs() < 1e-12);
    }
}
