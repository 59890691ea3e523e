//! Spectral-cube generation: a 256^2 x 128-channel H-alpha cube from the 64^3
//! Enzo snapshot (`shared/data/enzo-moving7`, seen along z, v_los -350..-150 km/s) and from
//! the 128^3 synthetic galaxy (128 x 128 x 64 voxels, edge-on along x, -300..300 km/s),
//! thermal broadening off and on, single-threaded (yt's PPVCube, timed by
//! `benches/scripts/yt_ppv_bench.py` on the same data, runs in one process). The Enzo cases
//! are skipped, with a printed reason, when the shared data is absent. Timings also go to
//! `target/blueshift-benches/doppler_cube.csv`. Group `doppler_cube_absorbing` times
//! absorbing cubes (black body, line absorption) with thermal broadening off and on.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use blueshift_benches::out_dir;
use blueshift_doppler::{
    CubeLineWidth, CubeSpec, DopplerScene, DopplerSettings, Species, SpectralAxis, los_camera,
    render_cube,
};
use blueshift_spectrum::Catalogue;
use blueshift_volume::{AnyGrid, synth};
use criterion::Criterion;
use glam::Vec3;

const HALPHA: f64 = 656.2816;

fn enzo_dir() -> Option<PathBuf> {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    [
        here.join("../../shared/data/enzo-moving7"),
        here.join("../../../shared/data/enzo-moving7"),
        PathBuf::from("/work/shared/data/enzo-moving7"),
    ]
    .into_iter()
    .find(|p| p.join("density_gcm3_64x64x64_f32le.nhdr").exists())
}

fn enzo_scene() -> Option<DopplerScene> {
    let dir = enzo_dir()?;
    let read = |name: &str| {
        blueshift_volume::read(dir.join(name))
            .expect("enzo nhdr")
            .channels()[0]
            .grid
            .clone()
    };
    let rho = read("density_gcm3_64x64x64_f32le.nhdr");
    let temp = read("temperature_K_64x64x64_f32le.nhdr");
    let AnyGrid::Vec3(mut vel) = read("velocity_kms_64x64x64x3_f32le.nhdr") else {
        panic!("velocity is not a vector channel");
    };
    for v in vel.data_mut() {
        *v *= 1e3; // km/s -> m/s
    }
    let mut scene = DopplerScene::new(*rho.geometry()).expect("scene");
    scene
        .add_species(Species {
            name: "H".into(),
            density: rho.clone().into(),
            emission_lines: Catalogue::HydrogenBalmer.lines(),
            absorption_lines: vec![],
        })
        .expect("species");
    scene.set_blackbody(rho, temp).expect("temperature");
    scene.factors.blackbody = 0.0;
    scene.set_velocity(vel).expect("velocity");
    Some(scene)
}

fn galaxy_scene() -> DopplerScene {
    let vol = synth::galaxy(128, 1).expect("galaxy");
    let mut s = DopplerScene::from_volume(&vol, &["bb", "H"]).expect("scene");
    s.factors.blackbody = 0.0;
    s
}

fn setup(
    scene: &DopplerScene,
    normal: Vec3,
    vmin: f64,
    vmax: f64,
    thermal: bool,
) -> (DopplerSettings, CubeSpec) {
    let mut st = DopplerSettings::default_for(scene, 256, 256);
    st.cell_domain = true;
    st.camera = los_camera(scene, normal, 1.0, true).expect("camera");
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: vmin * 1e3,
        max: vmax * 1e3,
        channels: 128,
        // A box one channel wide: yt's tent weights.
        line_width: CubeLineWidth::OneChannel,
    };
    st.broadening.thermal = thermal;
    (st, spec)
}

/// Group `doppler_cube_threads`: the galaxy's 128 x 128 x 64-channel cube, thermal
/// broadening off and on, on a pool of 1 and of 2 threads (the ratio 1 / 2 threads is the
/// scaling; thermal / unbroadened at 2 threads the cost of broadening).
fn threads(c: &mut Criterion) {
    let scene = galaxy_scene();
    let mut g = c.benchmark_group("doppler_cube_threads");
    for thermal in [false, true] {
        let (mut st, mut spec) = setup(&scene, Vec3::X, -300.0, 300.0, thermal);
        st.width = 128;
        st.height = 128;
        spec.channels = 64;
        for n in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .expect("pool");
            g.bench_function(format!("thermal_{thermal}/threads_{n}"), |b| {
                b.iter(|| pool.install(|| render_cube(&scene, &st, &spec, &|| {}).expect("cube")));
            });
        }
    }
    g.finish();
}

/// The Enzo snapshot with H I and He I (mass fractions 0.76, 0.24) that emit and absorb,
/// over the gas's black body: the scene of the absorbing cube measurements (issue 24.3).
fn enzo_absorbing_scene() -> Option<DopplerScene> {
    let dir = enzo_dir()?;
    let density = |fraction: f64| {
        format!(
            r#"{{ "file": "density_gcm3_64x64x64_f32le.nhdr", "unit": "g/cm3", "mass_fraction": {fraction} }}"#
        )
    };
    let text = format!(
        r#"{{
  "temperature": {{ "file": "temperature_K_64x64x64_f32le.nhdr", "unit": "K" }},
  "velocity": {{ "file": "velocity_kms_64x64x64x3_f32le.nhdr", "unit": "km/s", "subtract_mean": true }},
  "blackbody": {{ "density": {{ "file": "density_gcm3_64x64x64_f32le.nhdr", "unit": "g/cm3", "mass_fraction": 0.76, "scale": 1e9 }} }},
  "species": [
    {{ "name": "H I", "lines": "H", "density": {h} }},
    {{ "name": "He I", "lines": "He", "density": {he} }}
  ],
  "factors": {{ "velocity": 1, "temperature": 1, "emission": 1, "absorption": 1, "blackbody": 1 }}
}}"#,
        h = density(0.76),
        he = density(0.24)
    );
    let file = blueshift_doppler::SceneFile::parse(&text, &dir).expect("scene JSON");
    Some(file.load().expect("enzo scene"))
}

/// Group `doppler_cube_absorbing`: 64 x 64 x 24-channel H-alpha cubes (-300..300 km/s,
/// seen along z) of absorbing scenes, thermal broadening off and on, on the default pool
/// (the goal: thermal within 1.5x of unbroadened). The Enzo scene is skipped without the
/// shared data; the galaxy (64^3, absorption x5, black body x0.1) always runs.
fn absorbing(c: &mut Criterion) {
    let mut cases: Vec<(&str, DopplerScene)> = Vec::new();
    if let Some(s) = enzo_absorbing_scene() {
        cases.push(("enzo64", s));
    }
    let vol = synth::galaxy(64, 1).expect("galaxy");
    let mut galaxy = DopplerScene::from_volume(&vol, &["bb", "H"]).expect("scene");
    galaxy.factors.absorption = 5.0;
    galaxy.factors.blackbody = 0.1;
    cases.push(("galaxy64", galaxy));
    let mut g = c.benchmark_group("doppler_cube_absorbing");
    for (name, scene) in &cases {
        for thermal in [false, true] {
            let (mut st, mut spec) = setup(scene, Vec3::Z, -300.0, 300.0, thermal);
            st.width = 64;
            st.height = 64;
            spec.channels = 24;
            g.bench_function(format!("{name}/thermal_{thermal}"), |b| {
                b.iter(|| render_cube(scene, &st, &spec, &|| {}).expect("cube"));
            });
        }
    }
    g.finish();
}

fn main() {
    let mut c = Criterion::default().configure_from_args().sample_size(10);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut cases: Vec<(&str, DopplerScene, Vec3, f64, f64)> = Vec::new();
    match enzo_scene() {
        Some(s) => cases.push(("enzo64", s, Vec3::Z, -350.0, -150.0)),
        None => println!("skipping the Enzo cube: shared/data/enzo-moving7 not found"),
    }
    cases.push(("galaxy128", galaxy_scene(), Vec3::X, -300.0, 300.0));
    let mut csv = String::from("case,thermal,seconds_single_thread\n");
    let mut group = c.benchmark_group("doppler_cube_256x256x128");
    for (name, scene, normal, lo, hi) in &cases {
        for thermal in [false, true] {
            let (st, spec) = setup(scene, *normal, *lo, *hi, thermal);
            let t = Instant::now();
            let cube = pool.install(|| render_cube(scene, &st, &spec, &|| {}).expect("cube"));
            let secs = t.elapsed().as_secs_f64();
            let total: f64 = cube.data.iter().map(|&v| f64::from(v)).sum();
            println!("{name} thermal={thermal}: {secs:.3} s single-threaded, sum {total:.4e}");
            let _ = writeln!(csv, "{name},{thermal},{secs:.4}");
            group.bench_function(format!("{name}_thermal_{thermal}"), |b| {
                b.iter(|| pool.install(|| render_cube(scene, &st, &spec, &|| {}).expect("cube")));
            });
        }
    }
    group.finish();
    threads(&mut c);
    absorbing(&mut c);
    let path = out_dir().join("doppler_cube.csv");
    std::fs::write(&path, csv).expect("csv");
    println!("wrote {}", path.display());
    c.final_summary();
}
