//! The Enzo snapshot rendered from its AMR hierarchy (no resampling), against yt: the
//! projection of the density and the velocity structure of the level-7 clump, both made by
//! `tests/reference/yt_amr_enzo.py`.

use std::path::PathBuf;

use blueshift_camera::Camera;
use blueshift_doppler::{
    Broadening, CubeLineWidth, CubeSpec, DopplerScene, DopplerSettings, SceneFile, Species,
    SpectralAxis, SpectralCube, render_cube,
};
use blueshift_spectrum::EmissionLine;
use blueshift_volume::field::CombinedSource;
use blueshift_volume::{BrickCache, Field, Limits, VectorField};
use glam::Vec3;

const HALPHA: f64 = 656.279;

fn reference(name: &str) -> Vec<f32> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/reference/enzo_amr")
        .join(name);
    std::fs::read(p)
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn snapshot() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/enzo-moving7/original/moving7_0010")
}

/// The snapshot's gas as one H-alpha emitter whose emission is its density (g/cm^3), with
/// its velocity (m/s), read from the AMR hierarchy.
fn amr_scene() -> DopplerScene {
    let cache = BrickCache::new(256 << 20);
    let open = |name: &str| {
        blueshift_volume::amr::open_field(
            &snapshot(),
            Some(name),
            cache.clone(),
            &Limits::default(),
        )
        .unwrap()
        .1
    };
    let rho = open("Density");
    let comps = ["x-velocity", "y-velocity", "z-velocity"].map(|c| {
        Field::from(
            CombinedSource::monotone(&open(c), |v| (f64::from(v) * 1e-2) as f32)
                .field()
                .unwrap(),
        )
    });
    let mut scene = DopplerScene::new(*rho.geometry()).unwrap();
    scene
        .add_species(Species {
            name: "H".into(),
            density: rho.into(),
            emission_lines: vec![EmissionLine::new(HALPHA, 1.0).unwrap()],
            absorption_lines: vec![],
        })
        .unwrap();
    scene
        .set_velocity(VectorField::Components(Box::new(comps)))
        .unwrap();
    scene
}

/// A cube along -z (the observer at +z, yt's `v_los = -v_z`) over the window `lo..hi` (x, y)
/// through the whole depth, one channel wide lines.
fn cube(
    scene: &DopplerScene,
    lo: [f32; 2],
    hi: [f32; 2],
    px: usize,
    v: (f64, f64, usize),
) -> SpectralCube {
    let mut st = DopplerSettings::default_for(scene, px as u32, px as u32);
    st.cell_domain = true;
    let mut camera = Camera::framing(
        Vec3::new(lo[0], lo[1], 0.0),
        Vec3::new(hi[0], hi[1], 1.0),
        Vec3::Z,
        blueshift_camera::up_for(Vec3::Z),
        1.0,
        true,
        blueshift_camera::DEFAULT_FOV_Y_DEG,
    )
    .unwrap();
    camera.eye = camera.target + Vec3::Z * 2.0;
    st.camera = camera;
    st.broadening = Broadening {
        thermal: false,
        sigma_m_per_s: 0.0,
        masses_amu: vec![],
    };
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: v.0,
        max: v.1,
        channels: v.2,
        line_width: CubeLineWidth::OneChannel,
    };
    render_cube(scene, &st, &spec, &|| {}).unwrap()
}

const CODE_LENGTH_CM: f64 = 5.614_902_697_595_324e23;

/// Moment 0 along z of the AMR source over the whole domain against yt's projection (exact
/// path lengths through the leaf cells) in yt's default 30 x 30 buffer, which averages the
/// projected cells over each pixel's area; ours averages 4 x 4 rays per pixel at level 3
/// (cells of 1/128, about one per ray), each region at its own level.
///
/// The two reconstructions differ by design: yt's cells are constant, blueshift's tents
/// interpolate between cell centres, and 16 rays per pixel only approximate an area
/// average around the unresolved clump. What they share is the mass: linear interpolation
/// with clamped faces integrates to the cells' sum on a uniform grid. Stated tolerances:
/// the totals within 2 %, half the pixels within 3 %, the logarithms of the two maps
/// correlated above 0.98.
#[test]
fn projection_matches_yts_amr_projection() {
    let scene = amr_scene().at_level(4).unwrap();
    let (n, k) = (30usize, 4usize);
    let c = cube(&scene, [0.0, 0.0], [1.0, 1.0], n * k, (-3000e3, 3000e3, 4));
    let m0 = c.moments().m0;
    let mut ours = vec![0.0f64; n * n];
    for (i, &v) in m0.iter().enumerate() {
        let (x, y) = (i % (n * k), i / (n * k));
        ours[(y / k) * n + x / k] += f64::from(v) * CODE_LENGTH_CM / (k * k) as f64;
    }
    let yt = reference("proj_density_30.f32");
    assert_eq!(ours.len(), yt.len());
    let total: f64 = ours.iter().sum::<f64>() / yt.iter().map(|&v| f64::from(v)).sum::<f64>();
    let mut rel: Vec<f64> = ours
        .iter()
        .zip(&yt)
        .map(|(a, &b)| (a - f64::from(b)).abs() / f64::from(b))
        .collect();
    rel.sort_by(f64::total_cmp);
    let (median, worst) = (rel[rel.len() / 2], rel[rel.len() - 1]);
    let la: Vec<f64> = ours.iter().map(|v| v.ln()).collect();
    let lb: Vec<f64> = yt.iter().map(|&v| f64::from(v).ln()).collect();
    let mean = |a: &[f64]| a.iter().sum::<f64>() / a.len() as f64;
    let (ma, mb) = (mean(&la), mean(&lb));
    let cov: f64 = la.iter().zip(&lb).map(|(a, b)| (a - ma) * (b - mb)).sum();
    let var = |a: &[f64], m: f64| a.iter().map(|x| (x - m).powi(2)).sum::<f64>();
    let corr = cov / (var(&la, ma) * var(&lb, mb)).sqrt();
    println!("total ratio {total}, median {median}, worst {worst}, log correlation {corr}");
    assert!((total - 1.0).abs() < 0.02, "total ratio {total}");
    assert!(median < 0.03, "median {median}");
    assert!(corr > 0.98, "log correlation {corr}");
}

/// The clump at level 7: the intensity-weighted velocity of each pixel (one level-7 cell)
/// follows yt's line-of-sight integral over the leaf cells, pixel by pixel, while the
/// level-2 resample the scene files used holds almost none of that structure.
#[test]
fn clump_velocity_structure_matches_a_line_of_sight_integral() {
    let scene = amr_scene();
    let x0 = 0.749_023_44_f32;
    let w = 8.0 / 2048.0;
    let c = cube(&scene, [x0, x0], [x0 + w, x0 + w], 8, (-400e3, 100e3, 250));
    let m1: Vec<f64> = c
        .moments()
        .m1
        .iter()
        .map(|&v| -f64::from(v) / 1e3)
        .collect();
    let yt: Vec<f64> = reference("clump_vz_8.f32")
        .iter()
        .map(|&v| f64::from(v))
        .collect();
    let coarse: Vec<f64> = reference("clump_vz_level2_8.f32")
        .iter()
        .map(|&v| f64::from(v))
        .collect();
    let mean = |a: &[f64]| a.iter().sum::<f64>() / a.len() as f64;
    let std = |a: &[f64]| {
        let m = mean(a);
        (a.iter().map(|x| (x - m).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    };
    let corr = {
        let (ma, mb) = (mean(&m1), mean(&yt));
        let cov: f64 = m1
            .iter()
            .zip(&yt)
            .map(|(a, b)| (a - ma) * (b - mb))
            .sum::<f64>();
        cov / (m1.len() as f64 * std(&m1) * std(&yt))
    };
    let rms = (m1
        .iter()
        .zip(&yt)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / 64.0)
        .sqrt();
    println!(
        "ours mean {} std {}, yt mean {} std {}, level 2 std {}, corr {corr}, rms {rms}",
        mean(&m1),
        std(&m1),
        mean(&yt),
        std(&yt),
        std(&coarse)
    );
    assert!(
        std(&yt) > 10.0 * std(&coarse),
        "the reference shows the clump's structure"
    );
    assert!(corr > 0.9, "correlation {corr}");
    assert!(
        rms < 0.35 * std(&yt),
        "rms {rms} against a spread of {}",
        std(&yt)
    );
    assert!(
        (mean(&m1) - mean(&yt)).abs() < 2.0,
        "means {} {}",
        mean(&m1),
        mean(&yt)
    );
}

/// The committed scene file names the AMR hierarchy: it loads out of core, with every field
/// at the snapshot's finest level and each region at its own.
#[test]
fn amr_scene_file_loads() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/enzo-moving7-amr.json");
    let file = SceneFile::read(&path).unwrap();
    assert!(file.has_amr());
    let scene = file
        .load_within(
            None,
            &blueshift_doppler::MemoryVolumes::new(),
            Some(BrickCache::new(64 << 20)),
            &blueshift_volume::MemoryBudget::new(1 << 30, "test"),
        )
        .unwrap();
    assert_eq!(scene.geometry().dims, [2048, 2048, 2048]);
    let levels = scene.levels().expect("every field bricked alike");
    assert_eq!(levels.len(), 8);
    let d = scene.species()[0].density.as_bricked().unwrap();
    let hist = d.level_map().unwrap().histogram();
    // Most of the box is root cells, read at the coarsest level; the clump at the finest.
    assert!(hist[0] > 0 && hist[7] > hist[0] * 100, "{hist:?}");
}
