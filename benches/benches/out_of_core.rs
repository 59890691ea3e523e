//! Renders from `.bsv` bricks against the same render in core (issue 22): MDWT 1-DDA and
//! Doppler piecewise-linear, with a warm cache (every brick resident: the cost of sampling
//! through bricks) and cold (the cache cleared before every frame: the first frame, read
//! from the page cache). Goal: warm within 1.5x of in core. Ratios are against the in-core
//! time of the same run.

use std::sync::Arc;

use blueshift_doppler::{DopplerScene, DopplerSettings, Species, render_doppler};
use blueshift_spectrum::Catalogue;
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, render};
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Grid, synth};
use criterion::{Criterion, criterion_group, criterion_main};

fn f32_grid(v: blueshift_volume::Volume, name: &str) -> Grid<f32> {
    match &v.channel(name).expect("channel").grid {
        AnyGrid::F32(g) => g.clone(),
        _ => panic!("f32 channel"),
    }
}

/// `grid` as a `.bsv` in `dir` (bricks of 32), level 0 through `cache`.
fn bricked(dir: &std::path::Path, name: &str, grid: &Grid<f32>, cache: &Arc<BrickCache>) -> Field {
    let p = dir.join(format!("{name}.bsv"));
    ooc::convert(
        &mut GridSource(grid),
        &p,
        name,
        BrickLayout {
            brick: 32,
            apron: 1,
        },
        &mut |_, _| {},
    )
    .expect("convert");
    BrickedFile::open_with_cache(&p, cache.clone())
        .expect("open")
        .field(0)
        .expect("level 0")
        .into()
}

fn tracking(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let cache = BrickCache::new(1 << 30);
    let g = f32_grid(synth::turbulence(128, 1).expect("synth"), "density");
    let tf = blueshift_tfedit::builtin_over("viridis", [0.0, 1.0]).expect("tf");
    let scene =
        |f: Field| Scene::new(vec![("d".to_owned(), f, tf.clone())], 40.0, 4).expect("scene");
    let dense = scene(g.clone().into());
    let out = scene(bricked(dir.path(), "d", &g, &cache));
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let mut st = RenderSettings::default_for(&dense, 96, 96, false);
    st.spp = 2;
    let mut group = c.benchmark_group("out_of_core_mdwt_1dda_128cubed");
    group.sample_size(10);
    group.bench_function("in_core", |b| {
        b.iter(|| render(&dense, &integ, &st).expect("render"))
    });
    group.bench_function("bsv_warm", |b| {
        b.iter(|| render(&out, &integ, &st).expect("render"))
    });
    group.bench_function("bsv_cold", |b| {
        b.iter(|| {
            cache.clear();
            render(&out, &integ, &st).expect("render")
        })
    });
    group.finish();
}

fn doppler(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let cache = BrickCache::new(1 << 30);
    let hi = f32_grid(synth::galaxy(96, 1).expect("synth"), "hi_density");
    let g = *hi.geometry();
    let scene = |f: Field| {
        let mut s = DopplerScene::new(g).expect("scene");
        s.add_species(Species {
            name: "H".into(),
            density: f,
            emission_lines: Catalogue::HydrogenBalmer.lines(),
            absorption_lines: Catalogue::HydrogenBalmer.lines(),
        })
        .expect("species");
        s
    };
    let dense = scene(hi.clone().into());
    let out = scene(bricked(dir.path(), "hi", &hi, &cache));
    let st = DopplerSettings::default_for(&dense, 64, 64);
    let mut group = c.benchmark_group("out_of_core_doppler_pwl_96x96x48");
    group.sample_size(10);
    group.bench_function("in_core", |b| {
        b.iter(|| render_doppler(&dense, &st, &|| {}).expect("render"))
    });
    group.bench_function("bsv_warm", |b| {
        b.iter(|| render_doppler(&out, &st, &|| {}).expect("render"))
    });
    group.bench_function("bsv_cold", |b| {
        b.iter(|| {
            cache.clear();
            render_doppler(&out, &st, &|| {}).expect("render")
        })
    });
    group.finish();
}

criterion_group!(benches, tracking, doppler);
criterion_main!(benches);
