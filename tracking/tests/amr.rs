//! AMR output (the h5py-written Athena++ file of `volume/tests/data/amr`) renders with
//! every tracking method: its finest level is one brick, so the AMR source samples exactly
//! the reconstruction resampled dense at that level, and every method gives the dense
//! render's bytes at the same seed (the random numbers do not depend on where a value
//! lives). Majorants come from the leaf cells, never from a dense pass.

mod common;

use std::path::Path;

use blueshift_tracking::{Blend, DdaMode, Integrator, RayMarcher, RenderSettings, Scene, render};
use blueshift_volume::amr::{Hierarchy, open_field};
use blueshift_volume::{AnyGrid, BrickCache, Field, Limits};
use common::tf;

#[test]
fn every_method_renders_amr_output_as_its_dense_resample() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../volume/tests/data/amr/athena2.athdf");
    let (_, amr) = open_field(
        &path,
        Some("rho"),
        BrickCache::new(16 << 20),
        &Limits::default(),
    )
    .unwrap();
    assert!(
        amr.level_map().is_none(),
        "one brick: the finest level everywhere"
    );
    let dense = Hierarchy::open(&path)
        .unwrap()
        .field("rho", &Limits::default())
        .unwrap()
        .resample(1, &Limits::default())
        .unwrap();
    // rho runs from about -8 to 10 over the domain: a ramp over its upper half.
    let t = || tf([1.0, 0.6, 0.3], &[(0.0, 0.0), (10.0, 1.0)]);
    let a = Scene::new(
        vec![("rho".into(), Field::Dense(AnyGrid::F32(dense)), t())],
        3.0,
        4,
    )
    .unwrap();
    let b = Scene::new(vec![("rho".into(), Field::from(amr), t())], 3.0, 4).unwrap();
    for m in [
        Integrator::Woodcock { channel: 0 },
        Integrator::Mdwt {
            dda: DdaMode::NDda,
            blend: Blend::Density,
        },
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Max,
        },
        Integrator::Marcher(RayMarcher::default()),
    ] {
        let mut s = RenderSettings::default_for(&a, 24, 16, false);
        s.spp = 2;
        s.seed = 11;
        let x = render(&a, &m, &s).unwrap();
        let y = render(&b, &m, &s).unwrap();
        assert!(
            x.as_raw().iter().any(|&v| v > 0.0),
            "{m:?} renders something"
        );
        assert_eq!(x.as_raw(), y.as_raw(), "{m:?}");
    }
}
