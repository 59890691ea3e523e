//! A Doppler scene whose fields are `.bsv` files read through a small brick cache renders
//! the same XYZ bytes as the scene in memory (piecewise-linear, banded, with absorption,
//! the black body's derived emission bricks and a velocity given as three components), and
//! its spectral cube is the same too.

use blueshift_doppler::{
    CubeSpec, DopplerScene, DopplerSettings, Species, SpectralAxis, SpectralIntegrator,
    render_cube, render_doppler,
};
use blueshift_spectrum::Catalogue;
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Grid, VectorField, synth};

fn scalar(v: &blueshift_volume::Volume, name: &str) -> Grid<f32> {
    match &v.channel(name).unwrap().grid {
        AnyGrid::F32(g) => g.clone(),
        _ => panic!("f32"),
    }
}

#[test]
fn bricked_fields_render_the_in_core_bytes() {
    let vol = synth::galaxy(32, 2).unwrap();
    let (hi, temp) = (scalar(&vol, "hi_density"), scalar(&vol, "temperature_k"));
    let AnyGrid::Vec3(vel) = &vol.channel("velocity_m_per_s").unwrap().grid else {
        panic!("vector")
    };
    let g = *hi.geometry();
    let comp = |a: usize| Grid::from_vec(g, vel.data().iter().map(|v| v[a]).collect()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Room for 8 of the 32 bricks per field: evictions all along.
    let cache = BrickCache::new(8 * 10 * 10 * 10 * 4);
    let brick = |name: &str, grid: &Grid<f32>| -> Field {
        let p = dir.path().join(format!("{name}.bsv"));
        ooc::convert(
            &mut GridSource(grid),
            &p,
            name,
            BrickLayout { brick: 8, apron: 1 },
            &mut |_, _| {},
        )
        .unwrap();
        BrickedFile::open_with_cache(&p, cache.clone())
            .unwrap()
            .field(0)
            .unwrap()
            .into()
    };
    let lines = Catalogue::HydrogenBalmer.lines();
    let build = |density: Field, t: Field, v: VectorField| {
        let mut s = DopplerScene::new(g).unwrap();
        s.add_species(Species {
            name: "H".into(),
            density: density.clone(),
            emission_lines: lines.clone(),
            absorption_lines: lines.clone(),
        })
        .unwrap();
        s.set_blackbody(density, t).unwrap();
        s.set_velocity(v).unwrap();
        s.factors.blackbody = 1e-3;
        s.factors.velocity = 20.0;
        s
    };
    let dense = build(hi.clone().into(), temp.clone().into(), vel.clone().into());
    let bricked = build(
        brick("hi", &hi),
        brick("t", &temp),
        VectorField::Components(Box::new([
            brick("vx", &comp(0)),
            brick("vy", &comp(1)),
            brick("vz", &comp(2)),
        ])),
    );
    for (integrator, absorption) in [
        (SpectralIntegrator::PiecewiseLinear, 0.0),
        (SpectralIntegrator::PiecewiseLinear, 0.5),
        ("banded:16".parse().unwrap(), 0.0),
    ] {
        let (mut a, mut b) = (dense.clone(), bricked.clone());
        a.factors.absorption = absorption;
        b.factors.absorption = absorption;
        let st = DopplerSettings::default_for(&a, 12, 10);
        let x = render_doppler(&a, &st, &|| {}).unwrap();
        let y = render_doppler(&b, &st, &|| {}).unwrap();
        assert_eq!(x.xyz, y.xyz, "{integrator:?} absorption {absorption}");
    }
    let mut st = DopplerSettings::default_for(&dense, 8, 8);
    st.camera =
        blueshift_camera::Camera::default_view(g.world_bounds().0, g.world_bounds().1, 1.0, true);
    let spec = CubeSpec {
        rest_nm: 656.28,
        axis: SpectralAxis::OpticalVelocity,
        min: -3e5,
        max: 3e5,
        channels: 12,
        line_width: Default::default(),
    };
    let (x, y) = (
        render_cube(&dense, &st, &spec, &|| {}).unwrap(),
        render_cube(&bricked, &st, &spec, &|| {}).unwrap(),
    );
    assert_eq!(x.data, y.data);
    assert!(cache.stats().peak_bytes <= cache.budget());
}
