//! The renderer's fast per-pixel path against the exact formulas: the polynomial `atan2`
//! against libm's, the colour table uniform in `D` against the exact spectral matrix
//! `K(D)`, and a whole frame from an equirectangular map against a reference written out
//! here from the exact formulas (Eq. 2 aberration, `D = 1 / (gamma (1 - beta . d'))`,
//! `atan2`/`acos` map coordinates, `K(D)` from the spectra, `D^4`).

use blueshift_relativity::{
    ATAN2_MAX_ERROR_RAD, Camera, Checker, DopplerColourTable, Effects, Environment, EquirectMap,
    LINEAR_D_MAX_ERROR, SpectralPrimaries, TABLE_D_MAX, TABLE_D_MIN, Velocity, fast_atan2, render,
};
use glam::DVec3;
use image::Rgb32FImage;

/// Max |fast - libm| over a dense set of angles, radii and the special cases.
#[test]
fn fast_atan2_is_within_its_bound_of_libm() {
    let mut worst = 0.0_f64;
    let n = 200_000;
    for i in 0..=n {
        let a = -std::f64::consts::PI + std::f64::consts::TAU * f64::from(i) / f64::from(n);
        for r in [1e-300, 1e-3, 0.7, 1.0, 3.0e5] {
            let (y, x) = (r * a.sin(), r * a.cos());
            let e = (fast_atan2(y, x) - y.atan2(x)).abs();
            worst = worst.max(e);
        }
    }
    // Axes, diagonals and signed zeros give libm's quadrant.
    for (y, x) in [
        (0.0, 1.0),
        (-0.0, 1.0),
        (0.0, -1.0),
        (-0.0, -1.0),
        (1.0, 0.0),
        (-1.0, 0.0),
        (1.0, -0.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
        (0.0, 0.0),
        (-0.0, 0.0),
        (0.0, -0.0),
        (-0.0, -0.0),
    ] {
        let e = (fast_atan2(y, x) - f64::atan2(y, x)).abs();
        assert!(e <= ATAN2_MAX_ERROR_RAD, "atan2({y}, {x}): {e}");
        assert_eq!(
            fast_atan2(y, x).is_sign_negative(),
            f64::atan2(y, x).is_sign_negative(),
            "sign of atan2({y}, {x})"
        );
    }
    assert!(worst <= ATAN2_MAX_ERROR_RAD, "worst {worst:e} rad");
    // The bound is not loose by orders of magnitude (the polynomial errs by 7.8e-12).
    assert!(worst > 1e-13, "worst {worst:e} rad");
}

/// `K(D)` applied through the table uniform in `D` against the exact matrix from the
/// spectra, on a grid of `D` that falls between the table's nodes.
#[test]
fn linear_d_table_is_within_its_bound_of_the_exact_matrix() {
    let p = SpectralPrimaries::mallett_yuksel_2019().unwrap();
    let t = DopplerColourTable::global();
    let mut worst = 0.0_f64;
    let (mut worst_ln, mut at, mut at_ln) = (0.0_f64, 0.0, 0.0);
    let n = 700;
    for i in 0..=n {
        let d =
            TABLE_D_MIN + (TABLE_D_MAX - TABLE_D_MIN) * (f64::from(i) + 0.37) / f64::from(n + 1);
        let exact = p.doppler_matrix(d).unwrap();
        let scale = exact
            .iter()
            .flatten()
            .fold(0.0_f64, |m, v| m.max(v.abs()))
            .max(1e-3);
        // Columns of the table's matrix, read through unit colours.
        let ln = t.matrix(d);
        for j in 0..3 {
            let mut e = [0.0_f32; 3];
            e[j] = 1.0;
            let col = t.apply_linear_d(d, e);
            for r in 0..3 {
                let err = (f64::from(col[r]) - exact[r][j]).abs() / scale;
                if err > worst {
                    (worst, at) = (err, d);
                }
                let err_ln = (ln[r][j] - exact[r][j]).abs() / scale;
                if err_ln > worst_ln {
                    (worst_ln, at_ln) = (err_ln, d);
                }
            }
        }
    }
    println!(
        "worst relative error of K(D): linear in D {worst:e} at D = {at}, the ln D table \
         {worst_ln:e} at D = {at_ln}"
    );
    assert!(worst <= LINEAR_D_MAX_ERROR, "worst {worst:e}");
    // The resampling adds almost nothing to the ln D table's own interpolation error.
    assert!(worst <= worst_ln + 1e-5, "{worst:e} vs {worst_ln:e}");
    // Outside the range every colour is black, as with the ln D table.
    for d in [0.1, TABLE_D_MIN * 0.999, TABLE_D_MAX * 1.001, 5.0] {
        assert_eq!(t.apply_linear_d(d, [1.0, 2.0, 3.0]), [0.0; 3]);
        assert!(t.is_black_linear_d(d));
    }
}

/// A smooth map (bilinear sampling of it is close to the field, so a wrong texel shows).
fn smooth_map(w: u32, h: u32) -> EquirectMap {
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        let lon = (f64::from(x) + 0.5) / f64::from(w) * std::f64::consts::TAU;
        let polar = (f64::from(y) + 0.5) / f64::from(h) * std::f64::consts::PI;
        image::Rgb([
            (1.5 + lon.sin() * polar.sin()) as f32,
            (1.2 + (2.0 * lon).cos() * polar.sin()) as f32,
            (1.0 + 0.8 * polar.cos()) as f32,
        ])
    });
    EquirectMap::new(img).unwrap()
}

/// Bilinear sample of the map at the exact `(atan2(x, -z), acos(y))`, written out here.
fn exact_sample(img: &Rgb32FImage, d: DVec3) -> [f64; 3] {
    let (w, h) = img.dimensions();
    let lon = d.x.atan2(-d.z);
    let polar = d.y.clamp(-1.0, 1.0).acos();
    let x = (0.5 + lon / std::f64::consts::TAU) * f64::from(w) - 0.5;
    let y = (polar / std::f64::consts::PI * f64::from(h) - 0.5).clamp(0.0, f64::from(h - 1));
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let px = |i: i64, j: u32| {
        let p = img
            .get_pixel(i.rem_euclid(i64::from(w)) as u32, j.min(h - 1))
            .0;
        p.map(f64::from)
    };
    let (i, j) = (x0 as i64, y0 as u32);
    std::array::from_fn(|c| {
        let top = px(i, j)[c] * (1.0 - fx) + px(i + 1, j)[c] * fx;
        let bot = px(i, j + 1)[c] * (1.0 - fx) + px(i + 1, j + 1)[c] * fx;
        top * (1.0 - fy) + bot * fy
    })
}

/// Every 9th pixel of a frame with aberration, Doppler and searchlight against the exact
/// formulas: within the colour table's bound (times the pixel's colour) plus f32 rounding.
#[test]
fn equirect_frame_matches_the_exact_formulas() {
    let p = SpectralPrimaries::mallett_yuksel_2019().unwrap();
    let map = smooth_map(512, 256);
    let img_map = map.image().clone();
    let env = Environment::Equirect(map);
    let cam = Camera {
        look: DVec3::new(0.3, 0.1, -1.0),
        width: 96,
        height: 54,
        fov_y_deg: 100.0,
        ..Camera::default()
    };
    let beta = DVec3::new(0.25, -0.1, -0.5);
    let v = Velocity::new(beta).unwrap();
    let img = render(&env, &cam, v, Effects::ALL, None).unwrap();
    let frame = blueshift_relativity::CameraFrame::new(&cam).unwrap();
    let (b, u) = (beta.length(), beta.normalize());
    let g = 1.0 / (1.0 - b * b).sqrt();
    let mut checked = 0;
    for y in (0..54).step_by(3) {
        for x in (0..96).step_by(3) {
            let d_obs = frame.pixel_direction(f64::from(x), f64::from(y));
            // Eq. 2 (inverse aberration) written out.
            let c = d_obs.dot(u);
            let perp = d_obs - c * u;
            let d_scene = ((c - b) / (1.0 - b * c) * u + perp / (g * (1.0 - b * c))).normalize();
            let dop = 1.0 / (g * (1.0 - beta.dot(d_obs)));
            let rgb = exact_sample(&img_map, d_scene);
            let k = if (TABLE_D_MIN..=TABLE_D_MAX).contains(&dop) {
                p.doppler_matrix(dop).unwrap()
            } else {
                [[0.0; 3]; 3]
            };
            let scale = k
                .iter()
                .flatten()
                .fold(0.0_f64, |m, v| m.max(v.abs()))
                .max(1e-3);
            let d4 = dop.powi(4);
            let got = img.get_pixel(x, y).0;
            let mag = rgb.iter().sum::<f64>();
            for r in 0..3 {
                let want = (k[r][0] * rgb[0] + k[r][1] * rgb[1] + k[r][2] * rgb[2]) * d4;
                let tol = (LINEAR_D_MAX_ERROR * scale * mag + 1e-5 * want.abs()) * d4 + 1e-6;
                assert!(
                    (f64::from(got[r]) - want).abs() <= tol,
                    "pixel {x},{y} channel {r}: {} vs {want} (D {dop})",
                    got[r]
                );
            }
            checked += 1;
        }
    }
    assert!(checked > 500, "{checked}");
}

/// The fast equirectangular path sees the same cells as the checker it was made from, so a
/// wrong quadrant or pole would show as a wrong colour.
#[test]
fn equirect_render_agrees_with_the_checker_it_samples() {
    let checker = Checker {
        grid_deg: 0.0,
        cell_deg: 30.0,
        ..Checker::default()
    };
    let src = Environment::Checker(checker.clone());
    let eq = Environment::Equirect(src.to_equirect(1440, 720).unwrap());
    let cam = Camera {
        look: DVec3::new(0.2, 0.9, -0.4),
        width: 120,
        height: 80,
        fov_y_deg: 150.0,
        ..Camera::default()
    };
    let v = Velocity::along(DVec3::new(1.0, 0.5, 0.2), 0.7).unwrap();
    let a = render(&eq, &cam, v, Effects::ABERRATION, None).unwrap();
    let b = render(&src, &cam, v, Effects::ABERRATION, None).unwrap();
    let agree = a
        .pixels()
        .zip(b.pixels())
        .filter(|(p, q)| p.0.iter().zip(&q.0).all(|(s, t)| (s - t).abs() < 1e-4))
        .count();
    // Only pixels within a texel of a cell border may differ (bilinear blending there).
    assert!(agree as f64 > 0.97 * 9600.0, "{agree} of 9600 agree");
}
