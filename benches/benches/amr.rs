//! AMR (issue 25): the Enzo snapshot's hierarchy read natively, and a Doppler render from it
//! against the same field resampled dense.
//!
//! - `amr_read`: `Hierarchy::open` + the `Density` field of all 10 grids (the reader's
//!   throughput; h5py on the same file is timed by `benches/scripts/h5py_enzo_read.py`).
//! - `amr_render`: a 64 x 64 H-alpha render of the clump's octant (the level the view needs:
//!   4, cells of 1/256) from the AMR source (each region at its own level, bricks made on
//!   demand, warm cache) against the same field resampled dense at level 4 (256^3, in
//!   core). The dense grid is what the AMR source saves: 64 MiB per field at level 4 and
//!   32 GiB at the finest level 7, against 1.4 MB of AMR data.
//! - `amr_blocks`: a field of `n` one-cell root blocks each refined by a one-cell level-1
//!   block (`n` = 8000 and 64000) made in memory: leaf flags and sampling candidates find
//!   blocks by place, so 8x the blocks takes about 8x the time (a scan of every parent per
//!   child, as before, took 64x).

use std::hint::black_box;
use std::path::PathBuf;

use blueshift_camera::Camera;
use blueshift_doppler::{DopplerScene, DopplerSettings, Species, render_doppler};
use blueshift_spectrum::EmissionLine;
use blueshift_volume::amr::{AmrField, Block, FieldInfo, Hierarchy, open_field};
use blueshift_volume::{AnyGrid, BrickCache, Field, Limits};
use criterion::{Criterion, criterion_group, criterion_main};
use glam::{DVec3, Vec3};

fn snapshot() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/enzo-moving7/original/moving7_0010")
}

fn scene(density: Field) -> DopplerScene {
    let mut s = DopplerScene::new(*density.geometry()).expect("scene");
    s.add_species(Species {
        name: "H".into(),
        density,
        emission_lines: vec![EmissionLine::new(656.279, 1.0).expect("line")],
        absorption_lines: vec![],
    })
    .expect("species");
    s
}

fn settings(s: &DopplerScene) -> DopplerSettings {
    let mut st = DopplerSettings::default_for(s, 64, 64);
    let mut cam = Camera::framing(
        Vec3::new(0.5, 0.5, 0.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::Z,
        blueshift_camera::up_for(Vec3::Z),
        1.0,
        true,
        blueshift_camera::DEFAULT_FOV_Y_DEG,
    )
    .expect("camera");
    cam.eye = cam.target + Vec3::Z * 2.0;
    st.camera = cam;
    st
}

fn bench(c: &mut Criterion) {
    let path = snapshot();
    let mut g = c.benchmark_group("amr_read");
    g.sample_size(20);
    g.bench_function("enzo_density", |b| {
        b.iter(|| {
            let h = Hierarchy::open(&path).expect("open");
            black_box(h.field("Density", &Limits::default()).expect("field"))
        });
    });
    g.finish();

    let cache = BrickCache::new(512 << 20);
    let (_, amr) = open_field(&path, Some("Density"), cache, &Limits::default()).expect("amr");
    // Level 4 of the pyramid's 8 (index 3 from the finest).
    let amr = amr.at_level(3).expect("level 4");
    let amr_scene = scene(Field::from(amr));
    let dense = Hierarchy::open(&path)
        .expect("open")
        .field("Density", &Limits::default())
        .expect("field")
        .resample(4, &Limits::default())
        .expect("resample");
    let dense_scene = scene(Field::Dense(AnyGrid::F32(dense)));
    let (sa, sd) = (settings(&amr_scene), settings(&dense_scene));
    // Warm the brick cache.
    render_doppler(&amr_scene, &sa, &|| {}).expect("render");
    let mut g = c.benchmark_group("amr_render");
    g.sample_size(10);
    g.bench_function("dense_level4", |b| {
        b.iter(|| black_box(render_doppler(&dense_scene, &sd, &|| {}).expect("render")));
    });
    g.bench_function("amr_native_warm", |b| {
        b.iter(|| black_box(render_doppler(&amr_scene, &sa, &|| {}).expect("render")));
    });
    g.finish();
}

/// `n` one-cell root blocks on a cube of side `ceil(n^(1/3))` root cells, each under a
/// one-cell level-1 block, with their values.
fn many_blocks(n: usize) -> (Hierarchy, Vec<Vec<f32>>) {
    let side = (n as f64).cbrt().ceil() as usize;
    let mut blocks = Vec::with_capacity(2 * n);
    for level in 0..2u32 {
        for i in 0..n {
            let c = [i % side, (i / side) % side, i / (side * side)].map(|v| v as i64);
            blocks.push(Block {
                level,
                lo: c.map(|v| v << level),
                dims: [1, 1, 1],
            });
        }
    }
    let h = Hierarchy::new(DVec3::ZERO, DVec3::ONE, [side; 3], 2, blocks).expect("hierarchy");
    let values = vec![vec![1.0]; 2 * n];
    (h, values)
}

fn bench_blocks(c: &mut Criterion) {
    let mut g = c.benchmark_group("amr_blocks");
    g.sample_size(10);
    for n in [8000, 64000] {
        let (h, values) = many_blocks(n);
        let info = FieldInfo {
            name: "g".into(),
            unit: "code".into(),
            to_unit: 1.0,
        };
        g.bench_function(format!("field_of_{n}_refined_blocks"), |b| {
            b.iter(|| black_box(AmrField::new(&h, info.clone(), values.clone()).expect("field")));
        });
    }
    g.finish();
}

criterion_group!(benches, bench, bench_blocks);
criterion_main!(benches);
