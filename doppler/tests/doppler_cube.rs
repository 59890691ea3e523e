//! Spectral cubes: the Enzo snapshot against yt's PPVCube, a rotating shell's moment 1
//! against its analytic line-of-sight velocity, thermal broadening against the analytic
//! Gaussian and moment-0 conservation, the FITS layout against the FITS standard, bad input.

use std::path::PathBuf;

use blueshift_volume::synth;

use blueshift_doppler::{
    Broadening, CubeLineWidth, CubeMeta, CubeSpec, DopplerScene, DopplerSettings, Species,
    SpectralAxis, SpectralCube, fits_bytes, los_camera, nrrd_bytes, render_cube,
};
use blueshift_spectrum::{EmissionLine, SPEED_OF_LIGHT_M_PER_S};
use blueshift_volume::{AnyGrid, Geometry, Grid};
use glam::Vec3;

const HALPHA: f64 = 656.2816;

fn reference_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/reference/enzo_ppv")
}

fn read_f32(name: &str) -> Vec<f32> {
    let b = std::fs::read(reference_dir().join(name)).expect("committed reference file");
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// The Enzo crop as yt sees it: 32^3 cells of 1/64 code length from 0.5 to 1.
fn enzo_scene() -> DopplerScene {
    let n = 32;
    let geometry = Geometry {
        dims: [n, n, n],
        origin: Vec3::splat(0.5 + 0.5 / 64.0),
        spacing: Vec3::splat(1.0 / 64.0),
    };
    let rho =
        AnyGrid::F32(Grid::from_vec(geometry, read_f32("crop_density_gcm3_32x32x32.f32")).unwrap());
    let temp = AnyGrid::F32(
        Grid::from_vec(geometry, read_f32("crop_temperature_K_32x32x32.f32")).unwrap(),
    );
    let v = read_f32("crop_velocity_kms_32x32x32x3.f32");
    let vel: Vec<Vec3> = v
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]) * 1e3)
        .collect();
    let mut scene = DopplerScene::new(geometry).unwrap();
    scene
        .add_species(Species {
            name: "H".into(),
            density: (rho.clone()).into(),
            emission_lines: vec![EmissionLine::new(HALPHA, 1.0).unwrap()],
            absorption_lines: vec![],
        })
        .unwrap();
    scene.set_blackbody(rho, temp).unwrap();
    scene.factors.blackbody = 0.0;
    scene
        .set_velocity(Grid::from_vec(geometry, vel).unwrap())
        .unwrap();
    scene
}

fn enzo_cube(thermal: bool) -> SpectralCube {
    let scene = enzo_scene();
    let mut st = DopplerSettings::default_for(&scene, 32, 32);
    st.cell_domain = true;
    st.camera = los_camera(&scene, Vec3::Z, 1.0, true).unwrap();
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -260e3,
        max: -140e3,
        channels: 16,
        // Without broadening, a box one channel wide: its exact channel integrals are yt's
        // tent weights 1 - |v_c - v| / dv.
        line_width: CubeLineWidth::OneChannel,
    };
    st.broadening = Broadening {
        thermal,
        sigma_m_per_s: 0.0,
        masses_amu: vec![("H".into(), 1.007_947)],
    };
    render_cube(&scene, &st, &spec, &|| {}).unwrap()
}

/// Differences of a cube (scaled by `k`) from a reference.
#[derive(Debug)]
struct Diff {
    /// Max |a - b| over all values, relative to the reference's maximum.
    max_voxel: f64,
    /// Mean |a - b| relative to the mean |b|.
    mean_voxel: f64,
    /// Max |a - b| of the channel totals (the spectrum of the whole field), relative to the
    /// largest channel total.
    max_channel: f64,
    /// Relative difference of the totals (moment 0 of the field).
    total: f64,
}

fn compare(cube: &SpectralCube, reference: &[f32], k: f64) -> Diff {
    assert_eq!(cube.data.len(), reference.len());
    let max = reference.iter().fold(0.0f64, |m, &v| m.max(f64::from(v)));
    let (mut d, mut md, mut mb) = (0.0f64, 0.0, 0.0);
    let plane = cube.nx * cube.ny;
    let mut ch = vec![(0.0f64, 0.0f64); cube.spec.channels];
    for (i, (&a, &b)) in cube.data.iter().zip(reference).enumerate() {
        let (a, b) = (f64::from(a) * k, f64::from(b));
        d = d.max((a - b).abs());
        md += (a - b).abs();
        mb += b.abs();
        ch[i / plane].0 += a;
        ch[i / plane].1 += b;
    }
    let chmax = ch.iter().fold(0.0f64, |m, c| m.max(c.1));
    let (sa, sb): (f64, f64) = ch.iter().fold((0.0, 0.0), |s, c| (s.0 + c.0, s.1 + c.1));
    Diff {
        max_voxel: d / max,
        mean_voxel: md / mb,
        max_channel: ch.iter().fold(0.0f64, |m, c| m.max((c.0 - c.1).abs())) / chmax,
        total: (sa - sb) / sb,
    }
}

const CODE_LENGTH_CM: f64 = 5.6149e23;

/// The Enzo crop (32^3 cells around the collapsing clump, committed with the yt cubes made
/// by `tests/reference/yt_ppv_enzo.py`) against yt 4.4.3 / yt_astro_analysis 1.1.4
/// `PPVCube` along z, 16 channels of 7.5 km/s.
///
/// Truths and tolerances:
/// - moment 0 of the field (sum of all channels) equals the projected density
///   `sum rho dz` (numpy, in meta.json) to 1e-6 without and 1e-4 with thermal broadening
///   (the window holds > 99.99 % of the Gaussians);
/// - the field's spectrum (channel totals) agrees with yt within 2 % (thermal off) and with
///   yt's projection using exact erf channel weights within 3 % (thermal on); single
///   voxels within 12 % of the cube's maximum. What remains is sampling along the ray:
///   yt takes each cell's velocity as constant, blueshift interpolates velocity and
///   density trilinearly between cell centres, so a segment between two cells of
///   different velocity spreads its emission over the channels in between;
/// - yt's own thermal cube samples the Gaussian at channel centres (weight
///   `dv * G(v_c - v)`): with the crop's cold gas (median 1000 K, sigma 2.9 km/s for H, and
///   cells at 1 K) against 7.5 km/s channels it keeps only about 21 % of the emission;
///   blueshift's exact channel integrals keep all of it.
#[test]
fn enzo_cube_matches_yt_ppvcube() {
    let off = enzo_cube(false);
    let d_off = compare(&off, &read_f32("yt_thermal_off.f32"), CODE_LENGTH_CM);
    println!("thermal off vs yt: {d_off:?}");
    let on = enzo_cube(true);
    let d_erf = compare(&on, &read_f32("yt_thermal_on_erf.f32"), CODE_LENGTH_CM);
    println!("thermal on vs yt with erf weights: {d_erf:?}");
    let d_yt = compare(&on, &read_f32("yt_thermal_on.f32"), CODE_LENGTH_CM);
    println!("thermal on vs yt: {d_yt:?}");
    let meta: String = std::fs::read_to_string(reference_dir().join("meta.json")).unwrap();
    let key = "\"projected_density_sum_gcm2\": ";
    let i = meta.find(key).unwrap() + key.len();
    let projected: f64 = meta[i..]
        .split([',', '\n', '}'])
        .next()
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let total =
        |c: &SpectralCube| c.data.iter().map(|&v| f64::from(v)).sum::<f64>() * CODE_LENGTH_CM;
    assert!((total(&off) / projected - 1.0).abs() < 1e-6, "moment 0 off");
    assert!(
        (total(&on) / projected - 1.0).abs() < 1e-4,
        "moment 0 thermal"
    );
    assert!(
        d_off.total.abs() < 1e-6 && d_off.max_channel < 0.02,
        "{d_off:?}"
    );
    assert!(
        d_off.max_voxel < 0.12 && d_off.mean_voxel < 0.07,
        "{d_off:?}"
    );
    assert!(
        d_erf.total.abs() < 1e-4 && d_erf.max_channel < 0.03,
        "{d_erf:?}"
    );
    assert!(
        d_erf.max_voxel < 0.12 && d_erf.mean_voxel < 0.12,
        "{d_erf:?}"
    );
    // yt's sampled Gaussian weights lose most of the cold gas's emission.
    assert!(d_yt.total > 3.0, "{d_yt:?}");
}

fn halpha_species(density: AnyGrid) -> Species {
    Species {
        name: "H".into(),
        density: density.into(),
        emission_lines: vec![EmissionLine::new(HALPHA, 1.0).unwrap()],
        absorption_lines: vec![],
    }
}

/// The rigidly rotating hydrogen shell seen from +z: every sample along a ray has the
/// line-of-sight velocity `omega x` (v = (omega z, 0, -omega x), receding = -v_z), so
/// moment 1 must equal `omega x` at each pixel within one channel width.
#[test]
fn rotating_shell_moment_1_is_the_analytic_velocity() {
    let vol = synth::hydrogen_shell(32, 1).unwrap();
    let scene = DopplerScene::from_volume(&vol, &["H"]).unwrap();
    let (w, h) = (40u32, 40u32);
    let mut st = DopplerSettings::default_for(&scene, w, h);
    st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::RadioVelocity,
        min: -400e3,
        max: 400e3,
        channels: 40,
        line_width: CubeLineWidth::Settings,
    };
    st.line_width_nm = 0.05;
    let cube = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let m = cube.moments();
    let omega = synth::SHELL_SPEED_M_PER_S / synth::SHELL_RADIUS;
    let (lo, hi) = scene.geometry().world_bounds();
    let peak = m.m0.iter().fold(0.0f32, |a, &b| a.max(b));
    let mut checked = 0;
    for y in 0..cube.ny {
        for x in 0..cube.nx {
            let p = y * cube.nx + x;
            if m.m0[p] < 0.05 * peak {
                continue;
            }
            let wx = f64::from(lo.x) + (x as f64 + 0.5) * f64::from(hi.x - lo.x) / f64::from(w);
            let v = f64::from(omega) * wx;
            // The radio convention sees v / (1 + v / c): 0.3 km/s at 300 km/s.
            let vrad = v / (1.0 + v / SPEED_OF_LIGHT_M_PER_S);
            assert!(
                (f64::from(m.m1[p]) - vrad).abs() <= spec.width(),
                "pixel {x},{y}: moment 1 {} vs {vrad}",
                m.m1[p]
            );
            checked += 1;
        }
    }
    assert!(checked > 300, "{checked}");
}

fn slab_scene(t_k: f32, v_z: f32) -> DopplerScene {
    slab_scene_with(t_k, v_z, false)
}

/// A uniform hydrogen slab, column 1 along z; `absorbing`: H-alpha absorbs too.
fn slab_scene_with(t_k: f32, v_z: f32, absorbing: bool) -> DopplerScene {
    let g = Geometry {
        dims: [4, 4, 9],
        origin: Vec3::ZERO,
        spacing: Vec3::splat(0.125),
    };
    let mut scene = DopplerScene::new(g).unwrap();
    let rho = AnyGrid::F32(Grid::from_fn(g, |_, _, _| 1.0f32).unwrap());
    let mut species = halpha_species(rho.clone());
    if absorbing {
        species.absorption_lines = species.emission_lines.clone();
    }
    scene.add_species(species).unwrap();
    let temp = AnyGrid::F32(Grid::from_fn(g, |_, _, _| t_k).unwrap());
    scene.set_blackbody(rho, temp).unwrap();
    scene.factors.blackbody = 0.0;
    scene
        .set_velocity(Grid::from_fn(g, |_, _, _| Vec3::new(0.0, 0.0, v_z)).unwrap())
        .unwrap();
    scene
}

fn erf(x: f64) -> f64 {
    // Abramowitz & Stegun 7.1.26, |error| < 1.5e-7: enough for 1e-4 checks.
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let y = 1.0
        - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
            + 0.254_829_592)
            * t
            * (-x * x).exp();
    if x >= 0.0 { y } else { -y }
}

/// A uniform slab of hydrogen at 10^4 K moving at v_z = -30 km/s, seen from +z (receding at
/// +30 km/s): each pixel's channels are the exact channel integrals of a Gaussian of
/// sigma = sqrt(kT/m) = 9.08 km/s centred on +30 km/s, times the column; moment 0 equals the
/// unbroadened cube's moment 0 (broadening moves energy, it does not create it).
#[test]
fn thermal_channels_match_the_analytic_gaussian_and_keep_moment_0() {
    let scene = slab_scene(1e4, -30e3);
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -60e3,
        max: 120e3,
        channels: 36,
        line_width: CubeLineWidth::Settings,
    };
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
    st.line_width_nm = 0.01;
    let plain = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    st.broadening.thermal = true;
    let thermal = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let column = 1.0; // density 1 x depth 8 x 0.125
    let sigma = blueshift_spectrum::thermal_sigma_m_per_s(1e4, 1.008).unwrap();
    let (m0p, m0t) = (plain.moments().m0, thermal.moments().m0);
    for p in 0..16 {
        assert!(
            (f64::from(m0p[p]) - column).abs() < 1e-5,
            "plain moment 0 {}",
            m0p[p]
        );
        assert!(
            (f64::from(m0t[p]) / f64::from(m0p[p]) - 1.0).abs() < 1e-5,
            "thermal moment 0 {} vs {}",
            m0t[p],
            m0p[p]
        );
        let mut peak_err: f64 = 0.0;
        for k in 0..spec.channels {
            let (a, b) = (spec.edge(k), spec.edge(k + 1));
            let z = std::f64::consts::SQRT_2 * sigma;
            let exact = column * 0.5 * (erf((b - 30e3) / z) - erf((a - 30e3) / z));
            let got = f64::from(thermal.at(p % 4, p / 4, k));
            peak_err = peak_err.max((got - exact).abs());
        }
        // Channel integrals of the 0.87 %-sup-error PWL Gaussian: within 0.5 % of the
        // column (the largest channel holds 21 % of it).
        assert!(peak_err < 5e-3 * column, "pixel {p}: {peak_err}");
    }
}

/// A uniform slab of hydrogen at 10^4 K that emits and absorbs H-alpha (one thermal
/// profile `phi`, column 1) over a black body, seen through it: radiative transfer gives,
/// at each wavelength, `I = (E + C) (1 - exp(-g)) / g` with the line's emission `E = phi`,
/// its depth `g = f_a phi` and the continuum `C` the slab emits (constant across a
/// channel's 0.011 nm here). Each channel must be the integral of `I` (Simpson, 400
/// intervals) within 1 % of the peak channel and the cube's total within 0.2 %, for peak
/// depths of 0.01, 1, 10 and 100 (measured: 0.37 %, 0.25 %, 0.13 %, 0.59 %; the spectrum
/// path 0.77 % at 100), at a step of 1/512 (the segments' depth error is second order in
/// the step; at a peak depth of 1000 a segment holds a depth of 2 and both paths are off by
/// 4.5 % and 8 %). The continuum's part comes from the same cube with the line's emission
/// off and a negligible depth.
#[test]
fn absorbing_thermal_slab_matches_radiative_transfer() {
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -60e3,
        max: 60e3,
        channels: 24,
        line_width: CubeLineWidth::Settings,
    };
    let sigma_nm = HALPHA * blueshift_spectrum::thermal_sigma_m_per_s(1e4, 1.008).unwrap()
        / SPEED_OF_LIGHT_M_PER_S;
    let phi = |l: f64| {
        let z = (l - HALPHA) / sigma_nm;
        (-0.5 * z * z).exp() / ((2.0 * std::f64::consts::PI).sqrt() * sigma_nm)
    };
    let cube = |f_a: f64, emission: f64, blackbody: f64| {
        let mut scene = slab_scene_with(1e4, 0.0, true);
        scene.factors.absorption = f_a;
        scene.factors.emission = emission;
        scene.factors.blackbody = blackbody;
        let mut st = DopplerSettings::default_for(&scene, 2, 2);
        st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
        st.step = Some(1.0 / 512.0);
        st.broadening.thermal = true;
        let c = render_cube(&scene, &st, &spec, &|| {}).unwrap();
        (0..spec.channels)
            .map(|k| f64::from(c.at(0, 0, k)))
            .collect::<Vec<f64>>()
    };
    // The continuum about a fifth of the line's unabsorbed peak channel.
    let unit = cube(1e-12, 0.0, 1.0);
    let per_nm = unit.iter().sum::<f64>() / (spec.edge_nm(spec.channels) - spec.edge_nm(0));
    let blackbody = 0.2 * phi(HALPHA) / per_nm;
    for tau0 in [0.01, 1.0, 10.0, 100.0] {
        let f_a = tau0 / phi(HALPHA);
        let cont = cube(f_a * 1e-12, 0.0, blackbody);
        let got = cube(f_a, 1.0, blackbody);
        let expected: Vec<f64> = (0..spec.channels)
            .map(|k| {
                let (a, b) = (spec.edge_nm(k), spec.edge_nm(k + 1));
                let c_per_nm = cont[k] / (b - a);
                let n = 400;
                let h = (b - a) / f64::from(n);
                let i = |l: f64| {
                    let g = f_a * phi(l);
                    (phi(l) + c_per_nm) * (-g).exp_m1() / -g
                };
                (0..=n)
                    .map(|m| {
                        let w = if m == 0 || m == n {
                            1.0
                        } else if m % 2 == 1 {
                            4.0
                        } else {
                            2.0
                        };
                        w * i(a + h * f64::from(m))
                    })
                    .sum::<f64>()
                    * h
                    / 3.0
            })
            .collect();
        let peak = expected.iter().fold(0.0f64, |m, v| m.max(*v));
        let worst = got
            .iter()
            .zip(&expected)
            .map(|(g, e)| (g - e).abs())
            .fold(0.0f64, f64::max);
        let total = got.iter().sum::<f64>() / expected.iter().sum::<f64>() - 1.0;
        assert!(
            worst <= 1e-2 * peak && total.abs() <= 2e-3,
            "tau0 {tau0}: worst {:.2e} of the peak, total off by {total:.2e}",
            worst / peak
        );
    }
}

/// An absorbing, thermally broadened cube of a rotating galaxy seen edge-on over its black
/// body (a velocity gradient along every ray, so consecutive segments' lines drift) against
/// the spectrum path, an independent integrator of the same model: each pixel's
/// back-to-front spectrum (`pixel_spectrum`, merges at 1e-7, exact attenuation at depth
/// steps of 1e-3) integrated over each channel. `MEASURED` gives the worst differences, as
/// fractions of the cube's peak channel, at the merge tolerances the cube is rendered with;
/// each must stay within 1.5x of it. The depth models differ by the depth Gaussians'
/// pieces (the cube's lattice against the spectrum's 32 pieces, each within 0.8 % of a
/// line's peak depth), which sets the floor.
#[test]
fn absorbing_thermal_cube_matches_the_pixel_spectra() {
    const MEASURED: [(f64, f64); 2] = [(1e-4, 1.9e-3), (1e-2, 1.9e-3)];
    let vol = synth::galaxy(16, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    scene.factors.absorption = 20.0;
    scene.factors.blackbody = 0.3;
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -300e3,
        max: 300e3,
        channels: 24,
        line_width: CubeLineWidth::Settings,
    };
    let (w, h) = (8u32, 6u32);
    let mut st = DopplerSettings::default_for(&scene, w, h);
    st.camera = los_camera(&scene, Vec3::X, 8.0 / 6.0, true).unwrap();
    st.broadening.thermal = true;
    let mut exact = st.clone();
    exact.range_nm = (spec.edge_nm(0), spec.edge_nm(spec.channels));
    exact.merge_tolerance = 1e-7;
    exact.piece_budget = 1 << 24;
    exact.max_depth_step = 1e-3;
    let mut want = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = blueshift_doppler::pixel_spectrum(&scene, &exact, x, y).unwrap();
            for k in 0..spec.channels {
                want.push(p.integrate(spec.edge_nm(k), spec.edge_nm(k + 1)).unwrap());
            }
        }
    }
    let peak = want.iter().fold(0.0f64, |m, v| m.max(*v));
    assert!(peak > 0.0);
    for (tol, measured) in MEASURED {
        st.merge_tolerance = tol;
        let cube = render_cube(&scene, &st, &spec, &|| {}).unwrap();
        let mut worst = 0.0f64;
        for y in 0..h as usize {
            for x in 0..w as usize {
                for k in 0..spec.channels {
                    // FITS order: row 0 at the bottom.
                    let got = f64::from(cube.at(x, h as usize - 1 - y, k));
                    let i = (y * w as usize + x) * spec.channels + k;
                    worst = worst.max((got - want[i]).abs() / peak);
                }
            }
        }
        assert!(
            worst <= 1.5 * measured,
            "merge tolerance {tol}: {worst:.3e} of the peak (measured {measured:.1e})"
        );
    }
}

/// The merge tolerance bounds what the absorbing march gives up for speed (merges of the
/// depth in front, runs of segments swept together): a line that drifts by 4 sigma along
/// the ray (velocity from -20 to +20 km/s through a slab at 10^4 K) absorbs a black body;
/// against the same cube at a tolerance of 1e-9 (no runs, no merges) every channel stays
/// within `tol / 10` of the continuum there, for peak depths of 0.5 and 3 (the bounds: runs
/// `tol / 4 + tol / 8`, merges `tol / 32`; measured 0.022 tol). A run's continuum once took
/// the run's merged depth for the depth in front of each member: 0.24 tol here.
#[test]
fn absorbing_cube_errors_stay_within_the_merge_tolerance() {
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -60e3,
        max: 60e3,
        channels: 48,
        line_width: CubeLineWidth::Settings,
    };
    let g = Geometry {
        dims: [2, 2, 33],
        origin: Vec3::ZERO,
        spacing: Vec3::splat(1.0 / 32.0),
    };
    let rho = AnyGrid::F32(Grid::from_fn(g, |_, _, _| 1.0f32).unwrap());
    let mut scene = DopplerScene::new(g).unwrap();
    let mut species = halpha_species(rho.clone());
    species.absorption_lines = species.emission_lines.clone();
    scene.add_species(species).unwrap();
    let temp = AnyGrid::F32(Grid::from_fn(g, |_, _, _| 1e4f32).unwrap());
    scene.set_blackbody(rho, temp).unwrap();
    let vel = Grid::from_fn(g, |_, _, k| {
        Vec3::new(0.0, 0.0, (k as f32 / 32.0 - 0.5) * 40e3)
    });
    scene.set_velocity(vel.unwrap()).unwrap();
    scene.factors.emission = 0.0;
    let cube = |peak_depth: f64, tol: f64| {
        let mut scene = scene.clone();
        // Column 1: the peak depth of the line without drift is f_a / (sqrt(2 pi) sigma).
        let sigma_nm = HALPHA * blueshift_spectrum::thermal_sigma_m_per_s(1e4, 1.008).unwrap()
            / SPEED_OF_LIGHT_M_PER_S;
        scene.factors.absorption = peak_depth * (2.0 * std::f64::consts::PI).sqrt() * sigma_nm;
        let mut st = DopplerSettings::default_for(&scene, 1, 1);
        st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
        st.broadening.thermal = true;
        st.merge_tolerance = tol;
        let c = render_cube(&scene, &st, &spec, &|| {}).unwrap();
        c.data.into_iter().map(f64::from).collect::<Vec<f64>>()
    };
    let open = cube(1e-12, 1e-9);
    for peak_depth in [0.5, 3.0] {
        let exact = cube(peak_depth, 1e-9);
        assert!(
            exact.iter().zip(&open).any(|(e, o)| *e < 0.9 * o),
            "the line absorbs"
        );
        for tol in [1e-3, 1e-2] {
            let got = cube(peak_depth, tol);
            let worst = got
                .iter()
                .zip(&exact)
                .zip(&open)
                .map(|((g, e), o)| (g - e).abs() / (tol * o))
                .fold(0.0f64, f64::max);
            assert!(
                worst <= 0.1,
                "peak depth {peak_depth}, tolerance {tol}: {worst:.3} x the tolerance"
            );
        }
    }
}

/// The FITS file against the FITS standard: 80-character ASCII cards, mandatory keywords
/// in order, END, header and data each a multiple of 2880 bytes, big-endian f32 data in
/// NAXIS1-fastest order, and the WCS of the spectral axis.
#[test]
fn fits_layout_follows_the_standard() {
    let scene = slab_scene(1e4, -30e3);
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::RadioVelocity,
        min: -60e3,
        max: 120e3,
        channels: 5,
        line_width: CubeLineWidth::Settings,
    };
    let mut st = DopplerSettings::default_for(&scene, 3, 2);
    st.camera = los_camera(&scene, Vec3::Z, 1.5, false).unwrap();
    let cube = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let meta = CubeMeta {
        bunit: "g/cm2".into(),
        object: "slab".into(),
        world_unit: Some(("cm".into(), 2.0)),
    };
    let b = fits_bytes(&cube, &meta).unwrap();
    assert_eq!(b.len() % 2880, 0);
    let cards: Vec<String> = b
        .chunks(80)
        .map(|c| String::from_utf8_lossy(c).into_owned())
        .take_while(|c| !c.starts_with("END "))
        .collect();
    let header_cards = cards.len() + 1;
    let header_len = header_cards.div_ceil(36) * 2880;
    assert!(b[..header_len].iter().all(|c| (32..=126).contains(c)));
    for (i, key) in ["SIMPLE", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2", "NAXIS3"]
        .iter()
        .enumerate()
    {
        assert_eq!(cards[i][..8].trim_end(), *key);
        assert_eq!(&cards[i][8..10], "= ");
    }
    let value = |key: &str| -> String {
        let c = cards
            .iter()
            .find(|c| c[..8].trim_end() == key)
            .unwrap_or_else(|| panic!("no {key}"));
        let v = c[10..].split(" / ").next().unwrap().trim();
        v.trim_matches('\'').trim().to_owned()
    };
    // Fixed-format logical and integers right-justified to column 30.
    assert_eq!(&cards[0][29..30], "T");
    assert_eq!(cards[1][10..30].trim_start(), "-32");
    assert_eq!(value("NAXIS1"), "3");
    assert_eq!(value("NAXIS2"), "2");
    assert_eq!(value("NAXIS3"), "5");
    assert_eq!(value("CTYPE3"), "VRAD");
    assert_eq!(value("CUNIT3"), "m/s");
    assert_eq!(value("CUNIT1"), "cm");
    assert_eq!(value("BUNIT"), "g/cm2");
    let num = |k: &str| value(k).parse::<f64>().unwrap();
    assert_eq!(num("CRPIX3"), 1.0);
    assert!((num("CRVAL3") - (-42e3)).abs() < 1e-6);
    assert!((num("CDELT3") - 36e3).abs() < 1e-6);
    assert!((num("RESTWAV") - HALPHA * 1e-9).abs() < 1e-18);
    assert!((num("CRPIX1") - 2.0).abs() < 1e-12 && (num("CRPIX2") - 1.5).abs() < 1e-12);
    assert!((num("CDELT1") - 2.0 * cube.pixel_world.0).abs() < 1e-9);
    // Data: 3 x 2 x 5 big-endian f32 right after the header, zero padded.
    let n: usize = 3 * 2 * 5;
    assert_eq!(b.len(), header_len + (n * 4).div_ceil(2880) * 2880);
    for (i, c) in b[header_len..header_len + 4 * n].chunks(4).enumerate() {
        assert_eq!(f32::from_be_bytes([c[0], c[1], c[2], c[3]]), cube.data[i]);
    }
    assert!(b[header_len + 4 * n..].iter().all(|&x| x == 0));
    // NRRD: the volume crate's reader gets the same numbers back.
    let dir = std::env::temp_dir().join(format!("bs_cube_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("c.nrrd");
    std::fs::write(&p, nrrd_bytes(&cube).unwrap()).unwrap();
    let v = blueshift_volume::read(&p).unwrap();
    let g = &v.channels()[0].grid;
    assert_eq!(g.geometry().dims, [3, 2, 5]);
    assert_eq!(g.to_f32_vec(), cube.data);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_cube_input_is_refused() {
    let scene = slab_scene(1e4, 0.0);
    let st = DopplerSettings::default_for(&scene, 4, 4);
    let ok = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::RadioVelocity,
        min: -60e3,
        max: 60e3,
        channels: 8,
        line_width: CubeLineWidth::Settings,
    };
    assert!(render_cube(&scene, &st, &ok, &|| {}).is_ok());
    let bad = [
        CubeSpec {
            min: 10e3,
            max: 10e3,
            ..ok
        },
        CubeSpec {
            min: 10e3,
            max: -10e3,
            ..ok
        },
        CubeSpec { channels: 0, ..ok },
        CubeSpec {
            rest_nm: 1200.0,
            ..ok
        },
        CubeSpec {
            max: f64::NAN,
            ..ok
        },
        CubeSpec { max: 4e8, ..ok },
    ];
    for b in bad {
        let e = render_cube(&scene, &st, &b, &|| {})
            .unwrap_err()
            .to_string();
        assert!(!e.is_empty());
    }
    // A negative temperature in the data.
    let mut neg = slab_scene(-5.0, 0.0);
    neg.factors.blackbody = 0.0;
    let mut st2 = DopplerSettings::default_for(&neg, 4, 4);
    st2.broadening.thermal = true;
    let e = render_cube(&neg, &st2, &ok, &|| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("negative"), "{e}");
    // Factors that overflow the values: refused, not a cube of infinities or NaNs (a black
    // body at 1e300 gave infinities, an absorbing cube at a temperature factor of 1e300 was
    // all NaN).
    {
        let vol = synth::galaxy(16, 1).unwrap();
        let mut hot = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
        hot.factors.blackbody = 1e300;
        hot.factors.absorption = 1.0;
        let mut st3 = DopplerSettings::default_for(&hot, 4, 4);
        st3.camera = los_camera(&hot, Vec3::X, 1.0, true).unwrap();
        st3.broadening.thermal = true;
        let e = render_cube(&hot, &st3, &ok, &|| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("out of range"), "{e}");
    }
}

/// The image integrator uses the same profiles: a thermally broadened pixel spectrum keeps
/// the line's energy, is wider (second moment sigma^2 larger by the thermal sigma^2 in nm)
/// and the XYZ image barely changes (the CMFs vary little over 0.02 nm).
#[test]
fn image_integrator_broadens_lines_and_keeps_their_energy() {
    let scene = slab_scene(1e4, -30e3);
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
    st.line_width_nm = 0.001;
    let plain = blueshift_doppler::pixel_spectrum(&scene, &st, 1, 1).unwrap();
    let img0 = blueshift_doppler::render_doppler(&scene, &st, &|| {}).unwrap();
    st.broadening.thermal = true;
    let broad = blueshift_doppler::pixel_spectrum(&scene, &st, 1, 1).unwrap();
    let img1 = blueshift_doppler::render_doppler(&scene, &st, &|| {}).unwrap();
    assert!((broad.total() / plain.total() - 1.0).abs() < 1e-9);
    let var = |s: &blueshift_spectrum::PiecewiseLinear| {
        let n = 20000;
        let (a, b) = (HALPHA - 0.5, HALPHA + 0.5);
        let dx = (b - a) / f64::from(n);
        let (mut m0, mut m1, mut m2) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let x = a + (f64::from(i) + 0.5) * dx;
            let v = s.eval(x) * dx;
            m0 += v;
            m1 += v * x;
            m2 += v * x * x;
        }
        m2 / m0 - (m1 / m0).powi(2)
    };
    let sigma_nm = HALPHA * blueshift_spectrum::thermal_sigma_m_per_s(1e4, 1.008).unwrap()
        / SPEED_OF_LIGHT_M_PER_S;
    let added = var(&broad) - var(&plain);
    assert!(
        (added / (sigma_nm * sigma_nm) - 1.0).abs() < 0.03,
        "{added} vs {}",
        sigma_nm * sigma_nm
    );
    let (y0, y1) = (img0.xyz[5][1], img1.xyz[5][1]);
    assert!((y1 / y0 - 1.0).abs() < 1e-3, "{y0} {y1}");
}

/// The same cube on 1 thread and on the default pool, bit for bit; with line absorption
/// (each ray marched over the channels' window) no channel brightens, and the
/// absorbing path with a zero absorption factor equals the emission-only path.
#[test]
fn cubes_are_deterministic_and_absorption_never_brightens() {
    let vol = synth::hydrogen_shell(24, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["H"]).unwrap();
    let mut st = DopplerSettings::default_for(&scene, 16, 16);
    st.camera = los_camera(&scene, Vec3::new(0.3, 0.2, 1.0), 1.0, false).unwrap();
    st.broadening.sigma_m_per_s = 20e3;
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::RadioVelocity,
        min: -400e3,
        max: 400e3,
        channels: 24,
        line_width: CubeLineWidth::Settings,
    };
    let many = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let one = pool.install(|| render_cube(&scene, &st, &spec, &|| {}).unwrap());
    assert_eq!(many.data, one.data);
    scene.factors.absorption = 5.0;
    let absorbed = render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let (mut lost, mut total) = (0.0f64, 0.0f64);
    for (a, e) in absorbed.data.iter().zip(&many.data) {
        assert!(*a <= *e * (1.0 + 1e-4) + 1e-9, "{a} > {e}");
        lost += f64::from(e - a);
        total += f64::from(*e);
    }
    assert!(lost > 1e-3 * total, "absorption removed nothing");
}

/// The default [`CubeLineWidth::OneChannel`] is a box one channel wide (the channel width
/// in nm at the rest wavelength): the same cube, bit for bit, as the settings' line width
/// set to it by hand, on velocity and wavelength axes; `Settings` keeps the settings' width.
#[test]
fn one_channel_line_width_is_a_box_one_channel_wide() {
    let scene = slab_scene(1e4, -30e3);
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    st.camera = los_camera(&scene, Vec3::Z, 1.0, false).unwrap();
    for (axis, min, max) in [
        (SpectralAxis::OpticalVelocity, -60e3, 120e3),
        (SpectralAxis::RadioVelocity, -90e3, 90e3),
        (SpectralAxis::Wavelength, HALPHA - 0.2, HALPHA + 0.2),
    ] {
        let spec = CubeSpec {
            rest_nm: HALPHA,
            axis,
            min,
            max,
            channels: 12,
            line_width: CubeLineWidth::default(),
        };
        assert_eq!(spec.line_width, CubeLineWidth::OneChannel);
        let one = match axis {
            SpectralAxis::Wavelength => spec.width(),
            _ => HALPHA * spec.width() / SPEED_OF_LIGHT_M_PER_S,
        };
        assert_eq!(spec.line_width_nm(&st).to_bits(), one.to_bits(), "{axis}");
        let by_settings = CubeSpec {
            line_width: CubeLineWidth::Settings,
            ..spec
        };
        assert_eq!(by_settings.line_width_nm(&st), st.line_width_nm);
        let mut by_hand = st.clone();
        by_hand.line_width_nm = one;
        let auto = render_cube(&scene, &st, &spec, &|| {}).unwrap();
        let manual = render_cube(&scene, &by_hand, &by_settings, &|| {}).unwrap();
        assert_eq!(auto.data, manual.data, "{axis}");
        let wide = render_cube(&scene, &st, &by_settings, &|| {}).unwrap();
        assert_ne!(auto.data, wide.data, "{axis}: the 1 nm box should differ");
    }
}

/// A cube is the same, byte for byte, on pools of 1, 2 and 3 threads, without broadening
/// and with thermal broadening (whose wide Gaussians go through the kink bins).
#[test]
fn cubes_are_identical_on_one_two_and_three_threads() {
    let vol = synth::galaxy(24, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    scene.factors.blackbody = 0.0;
    for thermal in [false, true] {
        let mut st = DopplerSettings::default_for(&scene, 20, 12);
        st.camera = los_camera(&scene, Vec3::X, 20.0 / 12.0, true).unwrap();
        st.cell_domain = true;
        st.broadening.thermal = thermal;
        let spec = CubeSpec {
            rest_nm: HALPHA,
            axis: SpectralAxis::OpticalVelocity,
            min: -300e3,
            max: 300e3,
            channels: 48,
            line_width: CubeLineWidth::OneChannel,
        };
        let cubes: Vec<Vec<f32>> = [1, 2, 3]
            .into_iter()
            .map(|n| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build()
                    .unwrap();
                pool.install(|| render_cube(&scene, &st, &spec, &|| {}).unwrap().data)
            })
            .collect();
        assert!(
            cubes[0].iter().any(|&v| v > 0.0),
            "thermal {thermal}: empty cube"
        );
        assert_eq!(cubes[0], cubes[1], "thermal {thermal}: 1 vs 2 threads");
        assert_eq!(cubes[0], cubes[2], "thermal {thermal}: 1 vs 3 threads");
    }
}

/// Emission and absorption depend on lengths only through path integrals: a scene whose
/// spacing is multiplied by s, with its emission, absorption and black-body factors divided
/// by s, gives the same image and the same cube, in any units. Volumes in centimetres (1e21
/// cm per voxel) once failed: the squared diagonal overflowed f32 ("more than 1e6 steps per
/// ray").
#[test]
fn images_and_cubes_do_not_depend_on_the_unit_of_length() {
    let base = synth::galaxy(16, 1).unwrap();
    let run = |s: f32| {
        let mut vol = base.clone();
        let g = *vol.geometry();
        vol.set_geometry(Geometry {
            origin: g.origin * s,
            spacing: g.spacing * s,
            ..g
        })
        .unwrap();
        let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
        let k = 1.0 / f64::from(s);
        scene.factors.emission = k;
        scene.factors.absorption = 20.0 * k;
        scene.factors.blackbody = 0.1 * k;
        let mut st = DopplerSettings::default_for(&scene, 12, 10);
        st.incline(&scene, 60.0).unwrap();
        let image = blueshift_doppler::DopplerSession::new(scene.clone(), st.clone())
            .unwrap()
            .render(&blueshift_camera::Silent)
            .unwrap();
        let spec = CubeSpec {
            rest_nm: HALPHA,
            axis: SpectralAxis::OpticalVelocity,
            min: -300e3,
            max: 300e3,
            channels: 12,
            line_width: CubeLineWidth::OneChannel,
        };
        let mut cs = DopplerSettings::default_for(&scene, 8, 6);
        cs.camera = los_camera(&scene, Vec3::X, 8.0 / 6.0, true).unwrap();
        let cube = render_cube(&scene, &cs, &spec, &|| {}).unwrap().data;
        let xyz: Vec<f32> = image.xyz.iter().flatten().map(|&v| v as f32).collect();
        (xyz, cube)
    };
    let close = |a: &[f32], b: &[f32], what: &str| {
        let peak = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(peak > 0.0, "{what}: the reference is empty");
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst <= 1e-4 * peak, "{what}: worst {worst} of {peak}");
    };
    let (image, cube) = run(1.0);
    for s in [1e-30f32, 1e-9, 1e21, 1e30] {
        let (i, c) = run(s);
        close(&i, &image, &format!("image at {s} units per unit"));
        close(&c, &cube, &format!("cube at {s} units per unit"));
    }
}

/// An absorbing, thermally broadened cube holds only its window's pieces, so a small piece
/// budget changes it by no more than the merge tolerance allows. The budget's fallback once
/// kept raising its merge tolerance for the rest of each ray, over the whole 380-780 nm
/// spectrum, and the continuum beside the broadened lines came out many times too bright
/// (a 32x32 Enzo H-alpha cube's total +98 %).
#[test]
fn a_tight_piece_budget_keeps_an_absorbing_thermal_cube() {
    let vol = synth::galaxy(16, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    scene.factors.absorption = 5.0;
    scene.factors.blackbody = 0.1;
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -300e3,
        max: 300e3,
        channels: 24,
        line_width: CubeLineWidth::OneChannel,
    };
    let cube = |budget: usize| {
        let mut st = DopplerSettings::default_for(&scene, 8, 6);
        st.camera = los_camera(&scene, Vec3::X, 8.0 / 6.0, true).unwrap();
        st.broadening.thermal = true;
        st.piece_budget = budget;
        let c = render_cube(&scene, &st, &spec, &|| {}).unwrap().data;
        c.into_iter().map(f64::from).collect()
    };
    budgets_keep(cube, 2e-3, 1e-3);
}

/// Budgets of 64 and 256 pieces change `values(budget)` by at most `worst` of its peak in
/// any value and `total` of its sum, against a budget that never binds.
fn budgets_keep(values: impl Fn(usize) -> Vec<f64>, worst: f64, total: f64) {
    let exact = values(1 << 20);
    let peak = exact.iter().fold(0.0f64, |m, v| m.max(*v));
    assert!(peak > 0.0);
    for budget in [64, 256] {
        let got = values(budget);
        let w = got
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f64, f64::max);
        let rel = (got.iter().sum::<f64>() / exact.iter().sum::<f64>() - 1.0).abs();
        assert!(
            w <= worst * peak && rel < total,
            "budget {budget}: worst {w} of peak {peak}, total off by {rel}"
        );
    }
}

/// An absorbing, thermally broadened image at a small piece budget stays close to the
/// image at a budget that never binds: the budget's fallback merges coarsen one segment at a
/// time, never the rest of the ray (it once kept raising the ray's tolerance: a galaxy at
/// budget 64 was 4 % off in a pixel).
#[test]
fn a_tight_piece_budget_keeps_an_absorbing_thermal_image() {
    let vol = synth::galaxy(16, 1).unwrap();
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    scene.factors.absorption = 5.0;
    scene.factors.blackbody = 0.1;
    let image = |budget: usize| {
        let mut st = DopplerSettings::default_for(&scene, 16, 12);
        st.broadening.thermal = true;
        st.piece_budget = budget;
        let img = blueshift_doppler::DopplerSession::new(scene.clone(), st)
            .unwrap()
            .render(&blueshift_camera::Silent)
            .unwrap();
        img.xyz.iter().flatten().copied().collect::<Vec<f64>>()
    };
    budgets_keep(image, 5e-3, 2e-3);
}
