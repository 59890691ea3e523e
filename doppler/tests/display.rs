//! The display mapping keeps hue and luminance: spectral colours (outside every RGB gamut)
//! are desaturated towards the white of their own luminance, never clipped per channel, and
//! highlights roll off instead of clipping. Truths: the CIE 1931 colour matching functions,
//! the sRGB standard's luminance row (0.2126, 0.7152, 0.0722) and D65 white (0.3127, 0.3290).

use blueshift_doppler::{
    DisplayOptions, DopplerImage, DopplerScene, DopplerSession, DopplerSettings, GamutMapper,
    SHOULDER_KNEE, shoulder,
};
use blueshift_spectrum::{Cmf, srgb_decode, xyz_to_linear_srgb_matrix};
use blueshift_volume::synth;

const SRGB_Y: [f64; 3] = [0.2126, 0.7152, 0.0722];
const D65_XY: [f64; 2] = [0.3127, 0.3290];

fn xy(xyz: [f64; 3]) -> [f64; 2] {
    let s = xyz[0] + xyz[1] + xyz[2];
    [xyz[0] / s, xyz[1] / s]
}

/// The hue angle of a chromaticity around D65 white, radians.
fn hue(c: [f64; 2]) -> f64 {
    (c[1] - D65_XY[1]).atan2(c[0] - D65_XY[0])
}

fn srgb_to_xyz(rgb: [f64; 3]) -> [f64; 3] {
    let m = glam::DMat3::from_cols_array_2d(&xyz_to_linear_srgb_matrix())
        .transpose()
        .inverse();
    (m * glam::DVec3::from_array(rgb)).to_array()
}

#[test]
fn spectral_colours_keep_their_hue_and_luminance() {
    let g = GamutMapper::new(xyz_to_linear_srgb_matrix());
    let cmf = Cmf::cie1931_2deg();
    let mut checked = 0;
    for nm in (420..=680).step_by(5) {
        let bar = cmf.eval(f64::from(nm));
        for y in [0.02, 0.1, 0.3, 0.6, SHOULDER_KNEE] {
            let xyz = bar.map(|c| c * y / bar[1]);
            let rgb = g.map(xyz);
            assert!(
                rgb.iter().all(|c| (0.0..=1.0).contains(c)),
                "{nm} nm {rgb:?}"
            );
            let lum: f64 = rgb.iter().zip(SRGB_Y).map(|(c, w)| c * w).sum();
            assert!((lum - y).abs() < 2e-4 * y.max(0.01), "{nm} nm Y {y}: {lum}");
            // Same hue: the mapped colour lies on the line from white to the spectral colour.
            let back = srgb_to_xyz(rgb);
            let dh = (hue(xy(back)) - hue(xy(xyz))).abs();
            let dh = dh.min(std::f64::consts::TAU - dh);
            assert!(dh < 2e-3, "{nm} nm Y {y}: hue moved {dh} rad");
            checked += 1;
        }
    }
    assert_eq!(checked, 53 * 5);
    // Per-channel clipping would move the hue: H-alpha's red with its negative green.
    let bar = cmf.eval(656.28);
    let m = xyz_to_linear_srgb_matrix();
    let clipped =
        blueshift_spectrum::mat_mul(&m, bar.map(|c| c * 0.3 / bar[1])).map(|c| c.clamp(0.0, 1.0));
    let lum: f64 = clipped.iter().zip(SRGB_Y).map(|(c, w)| c * w).sum();
    assert!(
        (lum - 0.3).abs() > 0.05,
        "the clip happens to keep Y: {lum}"
    );
}

#[test]
fn the_shoulder_is_smooth_monotonic_and_never_reaches_one() {
    let k = SHOULDER_KNEE;
    assert_eq!(shoulder(0.5), 0.5);
    assert_eq!(shoulder(k), k);
    let h = 1e-6;
    let slope = (shoulder(k + h) - shoulder(k)) / h;
    assert!((slope - 1.0).abs() < 1e-5, "{slope}");
    let mut prev = 0.0;
    for i in 1..400 {
        let y = f64::from(i) * 0.01;
        let s = shoulder(y);
        assert!(s > prev && s < 1.0, "{y}: {s}");
        prev = s;
    }
}

/// The demo's view: the galaxy inclined 60 degrees, black body x0.1, H lines, velocity x30.
fn demo_image(velocity: f64) -> DopplerImage {
    let vol = synth::galaxy(32, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    scene.factors.blackbody = 0.1;
    scene.factors.velocity = velocity;
    let mut st = DopplerSettings::default_for(&scene, 64, 64);
    st.incline(&scene, 60.0).unwrap();
    let session = DopplerSession::new(scene, st).unwrap();
    session.render(&blueshift_camera::Silent).unwrap()
}

#[test]
fn the_demo_has_no_clipped_saturated_pixels_and_keeps_hue() {
    let img = demo_image(30.0);
    let disp = DisplayOptions::default();
    let rgb8 = disp.to_rgb8(&img);
    let k = disp.scale_for(&img);
    let m = xyz_to_linear_srgb_matrix();
    let (mut lit, mut bad, mut clip_bad) = (0, Vec::new(), 0);
    for (i, (p, x)) in rgb8.chunks_exact(3).zip(&img.xyz).enumerate() {
        if x[1] * k < 1e-3 {
            continue;
        }
        lit += 1;
        let lo = p.contains(&0);
        let hi = p.contains(&255);
        // A channel at 0 and one at 255 is allowed only where the XYZ itself is outside the
        // display gamut (a negative linear-sRGB channel) and there only on a few pixels.
        let lin = blueshift_spectrum::mat_mul(&m, x.map(|c| c * k));
        if lo && hi {
            assert!(
                lin.iter().any(|&c| c < 0.0),
                "pixel {i}: in gamut, yet {p:?}"
            );
            bad.push((i, p.to_vec()));
        }
        // What per-channel clipping (the old display) gives for this pixel.
        let clip =
            lin.map(|c| (blueshift_spectrum::srgb_encode(c.clamp(0.0, 1.0)) * 255.0).round());
        if clip.contains(&0.0) && clip.contains(&255.0) {
            clip_bad += 1;
        }
        // Hue: the displayed colour's chromaticity keeps the XYZ's hue angle.
        let rgb = [0, 1, 2].map(|c| srgb_decode(f64::from(p[c]) / 255.0));
        if rgb.iter().sum::<f64>() > 0.05 {
            let dh = (hue(xy(srgb_to_xyz(rgb))) - hue(xy(*x))).abs();
            let dh = dh.min(std::f64::consts::TAU - dh);
            // 8-bit rounding near the white point moves hue angles most; skip the greys.
            let shown = xy(srgb_to_xyz(rgb));
            let purity = (shown[0] - D65_XY[0]).hypot(shown[1] - D65_XY[1]);
            if purity > 0.03 {
                assert!(dh < 0.08, "pixel {i}: hue moved {dh} rad ({p:?})");
            }
        }
    }
    assert!(lit > 500, "{lit}");
    assert!(
        bad.len() * 1000 <= lit,
        "{} of {lit} pixels with a channel at 0 and one at 255: {:?}",
        bad.len(),
        &bad[..bad.len().min(5)]
    );
    // Per-channel clipping fails this by far (the flat saturated half of the old demo).
    assert!(clip_bad * 20 > lit, "clipping: {clip_bad} of {lit}");
    // The percentile exposure with the shoulder clips nothing: the brightest pixel is < 255
    // in luminance terms (not every channel at 255).
    assert!(rgb8.chunks_exact(3).all(|p| p != [255, 255, 255]));
}

/// The Doppler colour key of one 1 nm H-alpha box line: at each line-of-sight velocity its
/// chromaticity is that of the CIE 1931 functions averaged over the box shifted to
/// `656.28 (1 + v / c)` (classical Doppler, receding positive); with the velocity factor 0
/// every velocity gives the rest colour.
#[test]
fn the_colour_key_is_the_shifted_line_colour() {
    use blueshift_doppler::{Species, doppler_colour_key};
    use blueshift_spectrum::EmissionLine;
    use blueshift_volume::{AnyGrid, Geometry, Grid};
    let geom = Geometry {
        dims: [4, 4, 4],
        origin: glam::Vec3::ZERO,
        spacing: glam::Vec3::ONE,
    };
    let mut scene = DopplerScene::new(geom).unwrap();
    let line = EmissionLine {
        centre_nm: 656.28,
        strength: 1.0,
    };
    scene
        .add_species(Species {
            name: "H-alpha".into(),
            density: (AnyGrid::F32(Grid::from_fn(geom, |x, _, _| 0.5 + x as f32).unwrap())).into(),
            emission_lines: vec![line],
            absorption_lines: vec![],
        })
        .unwrap();
    let st = DopplerSettings::default_for(&scene, 8, 8);
    let c = 299_792_458.0;
    let cmf = Cmf::cie1931_2deg();
    let vs = [-2.0e7, -5.0e6, 0.0, 5.0e6, 1.0e7];
    let key = doppler_colour_key(&scene, &st, &vs).unwrap();
    for (v, xyz) in vs.iter().zip(&key) {
        let centre = 656.28 * (1.0 + v / c);
        let mut bar = [0.0f64; 3];
        for i in 0..1000 {
            let l = centre - 0.5 + (f64::from(i) + 0.5) / 1000.0;
            let e = cmf.eval(l);
            for k in 0..3 {
                bar[k] += e[k];
            }
        }
        let (got, want) = (xy(*xyz), xy(bar));
        assert!(
            (got[0] - want[0]).abs() < 2e-3 && (got[1] - want[1]).abs() < 2e-3,
            "v {v}: key xy {got:?}, shifted line {want:?}"
        );
    }
    let mut still = scene.clone();
    still.factors.velocity = 0.0;
    let key0 = doppler_colour_key(&still, &st, &vs).unwrap();
    for x in &key0 {
        assert_eq!(x, &key0[2]);
    }
    assert!(doppler_colour_key(&scene, &st, &[f64::NAN]).is_err());
}
