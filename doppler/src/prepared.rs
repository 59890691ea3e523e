//! The prepared form of a Doppler render: everything that depends on the scene and the
//! settings but not on the pixel, validated and built once.
//!
//! The CPU integrators (through [`crate::DopplerSession`], [`crate::render_doppler`], the
//! pickers and cubes) and the GPU uploader (`blueshift-gpu`'s `doppler` module) both read
//! it, so a rule changes in one place: the settings' validation and its error messages, the
//! piecewise-linear tables (CMF samples, the black-body grid and its hat functions' XYZ), the
//! banded layout with its CMF weights and rest-frame line values, the broadening tables, the
//! per-pixel rays clipped to the domain, and the line entries a device integrates.

use blueshift_spectrum::EmissionLine;

use super::banded::BandTables;
use super::model::DopplerScene;
use super::profile::Profiles;
use super::pwl::PwlTables;
use super::render::{BandShift, DopplerSettings, SpectralIntegrator};
use crate::{Error, Ray, Result};

/// Everything a render of one scene with one set of settings needs before its first ray.
///
/// Built by [`Prepared::new`], which validates the settings against the scene exactly as
/// every render entry point does (so the CPU and the GPU refuse the same inputs with the same
/// messages).
#[derive(Debug)]
pub struct Prepared {
    pub(crate) step: f32,
    pub(crate) pwl: Option<PwlTables>,
    pub(crate) banded: Option<BandTables>,
    pub(crate) profiles: Profiles,
    pub(crate) absorbing: bool,
    /// Every species' emission lines, then absorption lines, as `(species, line)` sorted by
    /// rest wavelength: without broadening a segment's lines come out in this order sorted
    /// by their middles and starts (one shift for all species), so no sort is needed.
    pub(crate) emission_order: Vec<(u32, u32)>,
    pub(crate) absorption_order: Vec<(u32, u32)>,
    /// Every species absorbs at exactly its emission lines' rest wavelengths, in the same
    /// order (so a segment's emission and absorption lines share their swept boxes).
    pub(crate) paired_lines: bool,
}

/// Which lines of a scene's species [`Prepared::line_entries`] lists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineKind {
    /// Emission lines (strength x emission factor).
    Emission,
    /// Absorption lines (strength x absorption factor).
    Absorption,
}

/// One line a device integrates: a rest wavelength, a strength (already times the scene's
/// emission or absorption factor) and the species it belongs to. For the paper's banded
/// integrator with the nearest-band shift the entries are the rest-frame band values
/// instead (one per non-empty band and species, at the band's centre).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineEntry {
    /// Rest wavelength (or band centre), nm.
    pub centre_nm: f64,
    /// Emitted area per unit density and length (emission) or optical depth per unit density
    /// and length (absorption), factors applied.
    pub strength: f64,
    /// Index of the species in [`DopplerScene::species`].
    pub species: usize,
}

/// Where a pixel's ray crosses the render domain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySpan {
    /// Ray parameter (world units) where the ray enters the domain.
    pub t0: f32,
    /// Path length inside the domain (world units).
    pub len: f32,
    /// Segments of at most one step (`ceil(len / step)`, at least 1).
    pub n_seg: u32,
}

impl RaySpan {
    /// The span of `ray` in the domain of `scene` (the box of the voxel centres, or of the
    /// cells with [`DopplerSettings::cell_domain`]) at step `step`; `None` when it misses or
    /// only touches it.
    #[must_use]
    pub fn clip(
        scene: &DopplerScene,
        settings: &DopplerSettings,
        step: f32,
        ray: &Ray,
    ) -> Option<Self> {
        let (lo, hi) = scene.frame_bounds(settings.cell_domain);
        let (t0, t1) = ray.clip_box(lo, hi)?;
        let len = t1 - t0;
        if len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let n_seg = (len / step).ceil().max(1.0) as u32;
        Some(Self { t0, len, n_seg })
    }
}

impl Prepared {
    /// Validates `settings` against `scene` and builds the tables of its integrator.
    ///
    /// # Errors
    /// [`Error::Parameter`] or [`Error::Scene`] naming the setting or field that is out of
    /// range (see [`DopplerSettings::validated_step`]); line broadening with a banded
    /// integrator; thermal broadening without a temperature field or an atomic mass.
    pub fn new(scene: &DopplerScene, settings: &DopplerSettings) -> Result<Self> {
        let step = settings.validated_step(scene)?;
        let (pwl, banded) = match settings.integrator {
            SpectralIntegrator::PiecewiseLinear => (Some(PwlTables::new(settings)), None),
            SpectralIntegrator::Banded { bands, shift } => {
                (None, Some(BandTables::new(scene, settings, bands, shift)?))
            }
        };
        if banded.is_some() && !settings.broadening.is_none() {
            return Err(Error::parameter(
                "line broadening (thermal or Gaussian) is implemented in the piecewise-linear \
                 integrator only: use the pwl integrator or drop the broadening",
            ));
        }
        let profiles = Profiles::new(scene, &settings.broadening)?;
        let order = |emission: bool| {
            let mut v: Vec<(f64, u32, u32)> = Vec::new();
            for (m, sp) in scene.species.iter().enumerate() {
                let list = if emission {
                    &sp.emission_lines
                } else {
                    &sp.absorption_lines
                };
                for (i, l) in list.iter().enumerate() {
                    v.push((l.centre_nm, m as u32, i as u32));
                }
            }
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v.into_iter().map(|(_, m, i)| (m, i)).collect()
        };
        Ok(Self {
            step,
            pwl,
            banded,
            profiles,
            absorbing: scene.absorbs(),
            emission_order: order(true),
            absorption_order: order(false),
            paired_lines: scene.species.iter().all(|sp| {
                sp.emission_lines.len() == sp.absorption_lines.len()
                    && sp
                        .emission_lines
                        .iter()
                        .zip(&sp.absorption_lines)
                        .all(|(e, a)| e.centre_nm == a.centre_nm)
            }),
        })
    }

    /// Rebuilds only what depends on the scene's [`crate::Factors`] (the banded rest-frame
    /// values and the absorbing flag) after a factor edit; the settings must be the ones
    /// this was prepared with.
    ///
    /// # Errors
    /// As [`Prepared::new`] (the factors are validated).
    pub fn refresh_factors(
        &mut self,
        scene: &DopplerScene,
        settings: &DopplerSettings,
    ) -> Result<()> {
        self.step = settings.validated_step(scene)?;
        if let SpectralIntegrator::Banded { bands, shift } = settings.integrator {
            self.banded = Some(BandTables::new(scene, settings, bands, shift)?);
        }
        self.absorbing = scene.absorbs();
        Ok(())
    }

    /// The ray step, world units.
    #[must_use]
    pub fn step(&self) -> f32 {
        self.step
    }

    /// Whether any line absorbs (absorption factor > 0 and some species has absorption
    /// lines): the piecewise-linear integrator then runs front to back.
    #[must_use]
    pub fn absorbing(&self) -> bool {
        self.absorbing
    }

    /// The piecewise-linear tables (`None` for the banded integrators).
    #[must_use]
    pub fn pwl_tables(&self) -> Option<&PwlTables> {
        self.pwl.as_ref()
    }

    /// The banded tables (`None` for the piecewise-linear integrator).
    #[must_use]
    pub fn band_tables(&self) -> Option<&BandTables> {
        self.banded.as_ref()
    }

    /// The line-broadening tables.
    #[must_use]
    pub fn profiles(&self) -> &Profiles {
        &self.profiles
    }

    /// The ray of pixel `(x, y)` (through the pixel centre) and its span in the domain
    /// (`None` when it misses), as every CPU render samples it.
    #[must_use]
    pub fn pixel_ray(
        &self,
        scene: &DopplerScene,
        settings: &DopplerSettings,
        x: u32,
        y: u32,
    ) -> (Ray, Option<RaySpan>) {
        let ray = settings.ray(x as f32 + 0.5, y as f32 + 0.5);
        let span = RaySpan::clip(scene, settings, self.step, &ray);
        (ray, span)
    }

    /// The lines of `kind` a device integrates, species by species: each line itself, or
    /// (banded, nearest shift) the rest-frame band values the CPU's Algorithm 1 moves.
    #[must_use]
    pub fn line_entries(&self, scene: &DopplerScene, kind: LineKind) -> Vec<LineEntry> {
        let f = scene.factors;
        let factor = match kind {
            LineKind::Emission => f.emission,
            LineKind::Absorption => f.absorption,
        };
        let mut out = Vec::new();
        if let Some(t) = self
            .banded
            .as_ref()
            .filter(|t| t.shift() == BandShift::Nearest)
        {
            for m in 0..scene.species.len() {
                let rest = match kind {
                    LineKind::Emission => t.rest_emission(m),
                    LineKind::Absorption => t.rest_absorption(m),
                };
                for &(i, x) in rest {
                    out.push(LineEntry {
                        centre_nm: t.centres()[i],
                        strength: x,
                        species: m,
                    });
                }
            }
            return out;
        }
        for (m, sp) in scene.species.iter().enumerate() {
            let list: &[EmissionLine] = match kind {
                LineKind::Emission => &sp.emission_lines,
                LineKind::Absorption => &sp.absorption_lines,
            };
            out.extend(list.iter().map(|l| LineEntry {
                centre_nm: l.centre_nm,
                strength: l.strength * factor,
                species: m,
            }));
        }
        out
    }
}
