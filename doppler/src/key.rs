//! Figure keys computed by the renderer itself: the Doppler colour key, the observed colour
//! of the scene's gas at each line-of-sight velocity.

use blueshift_volume::{AnyGrid, Field, Geometry, Grid};
use glam::Vec3;

use crate::{DopplerScene, DopplerSettings, Error, Result, Species, render_doppler};

/// Mean of a scalar grid (f64 sum).
fn mean(g: &Field) -> Result<f64> {
    Ok(g.mean()?)
}

/// Density-weighted mean of `value` (weights `density`); the plain mean when the densities
/// are all zero.
fn weighted_mean(value: &Field, density: &Field) -> Result<f64> {
    match value.weighted_mean(density)? {
        Some(m) => Ok(m),
        None => mean(value),
    }
}

/// The Doppler colour key: the XYZ that `settings` render for a unit slab of the scene's mean
/// gas (every species at its mean density, the black body at its mean density and its
/// density-weighted mean temperature, the scene's factors) moving at each line-of-sight
/// velocity of `velocities_m_per_s` (positive: receding from the observer; the velocity
/// factor applies as in the image). It shows which colour each velocity takes, including
/// why a receding pixel can look blue once H-alpha leaves the eye's range.
///
/// # Errors
/// [`Error::Parameter`] for a non-finite velocity or one of `|v| * factor >= c`, and the
/// renderer's errors.
pub fn doppler_colour_key(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    velocities_m_per_s: &[f64],
) -> Result<Vec<[f64; 3]>> {
    let geom = Geometry {
        dims: [2, 2, 2],
        origin: Vec3::ZERO,
        spacing: Vec3::ONE,
    };
    let constant = |v: f64| -> Result<AnyGrid> {
        Ok(AnyGrid::F32(Grid::from_fn(geom, move |_, _, _| v as f32)?))
    };
    let mut base = DopplerScene::new(geom)?;
    base.factors = scene.factors;
    for s in scene.species() {
        base.add_species(Species {
            name: s.name.clone(),
            density: constant(mean(&s.density)?)?.into(),
            emission_lines: s.emission_lines.clone(),
            absorption_lines: s.absorption_lines.clone(),
        })?;
    }
    if let Some((d, t)) = scene.blackbody() {
        base.set_blackbody(constant(mean(d)?)?, constant(weighted_mean(t, d)?)?)?;
    }
    let mut st = DopplerSettings::default_for(&base, 1, 1);
    st.model = settings.model;
    st.invariant = settings.invariant;
    st.integrator = settings.integrator;
    st.range_nm = settings.range_nm;
    st.line_width_nm = settings.line_width_nm;
    st.blackbody_samples = settings.blackbody_samples;
    st.merge_tolerance = settings.merge_tolerance;
    st.piece_budget = settings.piece_budget;
    st.max_depth_step = settings.max_depth_step;
    st.broadening = settings.broadening.clone();
    // The default view looks along -z: a receding velocity points along -z.
    let dir = st.camera.basis().0;
    velocities_m_per_s
        .iter()
        .map(|&v| {
            if !v.is_finite() {
                return Err(Error::parameter(format!("key velocity {v} must be finite")));
            }
            let mut sc = base.clone();
            let vel = dir * v as f32;
            sc.set_velocity(Grid::from_fn(geom, move |_, _, _| vel)?)?;
            Ok(render_doppler(&sc, &st, &|| {})?.xyz[0])
        })
        .collect()
}
