//! The spectral Doppler colour shift: exact at D = 1, tabulation error, black bodies.

use blueshift_relativity::{DopplerColourTable, SpectralPrimaries, TABLE_D_MAX, TABLE_D_MIN};
use blueshift_spectrum::{Blackbody, Cmf, Xyz, xyz_to_linear_srgb_matrix};

fn primaries() -> SpectralPrimaries {
    SpectralPrimaries::mallett_yuksel_2019().unwrap()
}

#[test]
fn upsampling_reproduces_rgb_and_is_non_negative() {
    let p = primaries();
    for rgb in [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.3, 0.5, 0.2],
    ] {
        let s = p.upsample(rgb).unwrap();
        let back = Cmf::cie1931_2deg().xyz_of(&s).to_linear_srgb();
        for c in 0..3 {
            assert!((back[c] - rgb[c]).abs() < 3e-3, "{rgb:?} -> {back:?}");
        }
        // Mallett-Yuksel: in-gamut colours have non-negative spectra.
        let min = s
            .pieces()
            .map(|q| q.value_start.min(q.value_end))
            .fold(f64::INFINITY, f64::min);
        assert!(min >= -1e-12, "{rgb:?}: min {min}");
    }
    // Inside the gamut the round trip is exact.
    let rgb = [0.3, 0.5, 0.2];
    let back = Cmf::cie1931_2deg()
        .xyz_of(&p.upsample(rgb).unwrap())
        .to_linear_srgb();
    for c in 0..3 {
        assert!((back[c] - rgb[c]).abs() < 1e-9);
    }
    assert!(p.upsample([-0.5, 1.0, 0.0]).is_err());
    let k = p.doppler_matrix(1.0).unwrap();
    for i in 0..3 {
        for j in 0..3 {
            let id = if i == j { 1.0 } else { 0.0 };
            assert!((k[i][j] - id).abs() < 1e-9);
        }
    }
}

/// The table interpolates the exact matrix to 1e-4 of its largest entry and is exactly zero
/// where the shifted basis leaves 360-830 nm.
#[test]
fn table_matches_exact_matrices() {
    let p = primaries();
    let t = DopplerColourTable::new(&p, 2048).unwrap();
    for d in [0.5, 0.61, 0.8, 0.97, 1.0, 1.03, 1.3, 1.7, 2.1] {
        let exact = p.doppler_matrix(d).unwrap();
        let approx = t.matrix(d);
        let scale = exact
            .iter()
            .flatten()
            .fold(0.0_f64, |m, v| m.max(v.abs()))
            .max(1e-3);
        for i in 0..3 {
            for j in 0..3 {
                assert!((exact[i][j] - approx[i][j]).abs() < 1e-4 * scale, "D {d}");
            }
        }
    }
    for d in [0.1, TABLE_D_MIN * 0.99, TABLE_D_MAX * 1.01, 14.0] {
        assert_eq!(t.matrix(d), [[0.0; 3]; 3]);
        assert_eq!(p.doppler_matrix(d).unwrap(), [[0.0; 3]; 3]);
    }
}

fn xy(rgb: [f64; 3]) -> ([f64; 2], f64) {
    let m = blueshift_spectrum::linear_srgb_to_xyz_matrix();
    let xyz = Xyz::from_array(blueshift_spectrum::mat_mul(&m, rgb));
    (xyz.chromaticity().unwrap(), xyz.y)
}

/// A black-body texel at T seen with Doppler factor D (searchlight on, i.e. the invariant
/// transform) against the black body at D T. The texel holds only the black body's linear
/// sRGB, so the seen colour carries the upsampling error, which grows with |ln D| because the
/// upsampled spectrum is zero outside 380-780 nm (no ultraviolet or infrared to shift in).
/// Measured (printed by this test) over T in 4000-12000 K and D in 0.95-1.1: worst
/// chromaticity error |dxy| = 0.036 (12000 K, D = 0.95) and relative luminance error 4.9%
/// (12000 K, D = 1.1); the limits add a small margin. (At D = 0.85 or 1.2 the error reaches
/// |dxy| = 0.2 and 21% in Y; see the crate README.)
#[test]
fn black_body_texel_shifts_to_black_body_at_d_t() {
    let table = DopplerColourTable::global();
    let to_rgb = xyz_to_linear_srgb_matrix();
    let mut worst_xy = 0.0_f64;
    let mut worst_y = 0.0_f64;
    for t_k in [4000.0, 5800.0, 8000.0, 12000.0] {
        // Scale to keep numbers near 1 (the same scale on both sides).
        let scale = 1.0 / Blackbody::new(t_k).unwrap().xyz().y;
        let rgb = blueshift_spectrum::mat_mul(
            &to_rgb,
            Blackbody::new(t_k).unwrap().xyz().scaled(scale).to_array(),
        );
        for d in [0.95, 0.97, 1.0, 1.03, 1.05, 1.1] {
            let k = table.matrix(d);
            let seen: [f64; 3] = std::array::from_fn(|i| {
                d.powi(4) * (k[i][0] * rgb[0] + k[i][1] * rgb[1] + k[i][2] * rgb[2])
            });
            let truth = blueshift_spectrum::mat_mul(
                &to_rgb,
                Blackbody::new(d * t_k)
                    .unwrap()
                    .xyz()
                    .scaled(scale)
                    .to_array(),
            );
            let (xy_s, y_s) = xy(seen);
            let (xy_t, y_t) = xy(truth);
            let dxy = (xy_s[0] - xy_t[0]).hypot(xy_s[1] - xy_t[1]);
            worst_xy = worst_xy.max(dxy);
            worst_y = worst_y.max((y_s / y_t - 1.0).abs());
        }
    }
    println!("black body: worst |dxy| = {worst_xy:.4}, worst relative Y = {worst_y:.4}");
    assert!(worst_xy < 0.04, "worst |dxy| = {worst_xy}");
    assert!(worst_y < 0.055, "worst relative Y = {worst_y}");
}
