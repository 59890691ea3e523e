//! The emission-absorption model of Eq. 8: species, black body, velocity and factors.

use blueshift_spectrum::{Catalogue, EmissionLine};
use blueshift_volume::{AnyGrid, Field, Geometry, Grid, VectorField, Volume};
use glam::Vec3;

use crate::{Error, Result};

/// Black-body radiance unit: `B(lambda, T)` (W sr^-1 m^-2 nm^-1) is multiplied by this, so a
/// 5800 K black body peaks near 2.6 (in units of 1e13 W sr^-1 m^-2 nm^-1).
pub const BB_UNIT: f64 = 1e-13;

/// User multipliers of the paper's Table 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Factors {
    /// Multiplies every velocity before the Doppler shift (0 turns Doppler off).
    pub velocity: f64,
    /// Multiplies every temperature.
    pub temperature: f64,
    /// Multiplies line emission.
    pub emission: f64,
    /// Multiplies line absorption (0: emission only).
    pub absorption: f64,
    /// Multiplies black-body emission.
    pub blackbody: f64,
}

impl Default for Factors {
    fn default() -> Self {
        Self {
            velocity: 1.0,
            temperature: 1.0,
            emission: 1.0,
            absorption: 0.0,
            blackbody: 1.0,
        }
    }
}

/// Reference wavelength of the black body's temperature reconstruction, nm.
pub const BB_REF_NM: f64 = 700.0;

/// `c2 = h c / k_B` in nm K (CODATA), the constant of the temperature reconstruction.
const C2_NM_K: f64 = 1.438_776_877_5e7;

/// The Planck factor `1 / (exp(c2 / (lambda_ref T)) - 1)` at [`BB_REF_NM`] (0 for `T <= 0`).
#[must_use]
pub fn planck_factor(temperature_k: f64) -> f64 {
    if temperature_k > 0.0 {
        1.0 / (C2_NM_K / (BB_REF_NM * temperature_k)).exp_m1()
    } else {
        0.0
    }
}

/// The temperature whose [`planck_factor`] is `factor` (its inverse), 0 for factors below
/// 1e-30 (under about 300 K; the GPU kernels use the same cut).
#[must_use]
pub fn brightness_temperature(factor: f64) -> f64 {
    if factor > 1e-30 && factor.is_finite() {
        C2_NM_K / (BB_REF_NM * (1.0 / factor).ln_1p())
    } else {
        0.0
    }
}

/// One species of Eq. 8: a density channel with emission lines (`E_m`) and absorption lines
/// (`A_m`, optical depth per unit density and world length, per nm of line area).
#[derive(Clone, Debug)]
pub struct Species {
    /// Name (for messages).
    pub name: String,
    /// Number density, on the scene's geometry (dense, or a level of a bricked file).
    pub density: Field,
    /// Emission lines (strength = line area per unit density and length).
    pub emission_lines: Vec<EmissionLine>,
    /// Absorption lines (strength = optical-depth area per unit density and length).
    pub absorption_lines: Vec<EmissionLine>,
}

/// The scene: species, an optional black body and an optional velocity field, all on one
/// geometry.
#[derive(Clone, Debug)]
pub struct DopplerScene {
    pub(crate) geometry: Geometry,
    /// The finest level's geometry (the scene's own at level 0): rays are clipped to its
    /// box and default views frame it at every level of detail.
    pub(crate) frame: Geometry,
    pub(crate) species: Vec<Species>,
    pub(crate) blackbody: Option<(Field, Field)>,
    /// Black-body density times the Planck factor `1 / (exp(c2 / (lambda_ref T)) - 1)` per
    /// voxel (see [`DopplerScene::set_blackbody`]).
    pub(crate) rho_t: Option<Field>,
    pub(crate) velocity: Option<VectorField>,
    /// User factors.
    pub factors: Factors,
}

fn check_geometry(what: &str, g: &Geometry, want: &Geometry) -> Result<()> {
    if g.dims != want.dims {
        return Err(Error::scene(format!(
            "{what}: dims {:?} differ from the scene's {:?}",
            g.dims, want.dims
        )));
    }
    Ok(())
}

fn scalar(what: &str, g: &Field) -> Result<()> {
    if g.is_vector() {
        return Err(Error::scene(format!("{what} must be a scalar channel")));
    }
    g.reject_non_finite()?;
    Ok(())
}

impl DopplerScene {
    /// An empty scene on `geometry`.
    pub fn new(geometry: Geometry) -> Result<Self> {
        geometry.validate()?;
        Ok(Self {
            geometry,
            frame: geometry,
            species: Vec::new(),
            blackbody: None,
            rho_t: None,
            velocity: None,
            factors: Factors::default(),
        })
    }

    /// Whether any line absorbs: the absorption factor is > 0 and some species has
    /// absorption lines (the piecewise-linear integrator then runs front to back).
    #[must_use]
    pub fn absorbs(&self) -> bool {
        self.factors.absorption > 0.0
            && self
                .species
                .iter()
                .any(|sp| !sp.absorption_lines.is_empty())
    }

    /// The scene's geometry.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// The finest level's geometry: the scene's own at level 0, the same at every level of
    /// detail ([`DopplerScene::at_level`]).
    #[must_use]
    pub fn frame_geometry(&self) -> &Geometry {
        &self.frame
    }

    /// The world box rays are clipped to and default views frame, at every level of detail:
    /// the finest level's voxel centres, or its cells with `cell_domain` (half a finest
    /// voxel more on each side). A coarser level's own voxel centres lie up to half a
    /// coarse voxel inside it; samples there clamp to the edge voxels.
    #[must_use]
    pub fn frame_bounds(&self, cell_domain: bool) -> (Vec3, Vec3) {
        let (mut lo, mut hi) = self.frame.world_bounds();
        if cell_domain {
            lo -= 0.5 * self.frame.spacing;
            hi += 0.5 * self.frame.spacing;
        }
        (lo, hi)
    }

    /// The species.
    #[must_use]
    pub fn species(&self) -> &[Species] {
        &self.species
    }

    /// The black body's `(density, temperature_k)` channels, if set (read-only; for backends
    /// such as blueshift-gpu that mirror the renderer).
    #[must_use]
    pub fn blackbody(&self) -> Option<(&Field, &Field)> {
        self.blackbody.as_ref().map(|(d, t)| (d, t))
    }

    /// The velocity field (m/s), if set (read-only).
    #[must_use]
    pub fn velocity(&self) -> Option<&VectorField> {
        self.velocity.as_ref()
    }

    /// Adds a species (scalar density on the scene's dims, finite, non-negative lines).
    pub fn add_species(&mut self, species: Species) -> Result<()> {
        scalar(&species.name, &species.density)?;
        check_geometry(&species.name, species.density.geometry(), &self.geometry)?;
        self.species.push(species);
        Ok(())
    }

    /// Black-body emission `density * B(lambda, temperature_k)`. Between voxels the black
    /// body's temperature is the brightness temperature at [`BB_REF_NM`] of the interpolated
    /// emission: `T` such that `rho B(lambda_ref, T) = interp(rho_i B(lambda_ref, T_i))`
    /// with `rho = interp(rho_i)` ([`brightness_temperature`]), so the black-body emission
    /// between voxels is the interpolation of theirs (exactly at `lambda_ref`). Interpolating
    /// `T` itself and then taking the steep `B(T)` makes the emission between two warm
    /// voxels far less than either (a lattice of bright dots at the voxels on thin hot
    /// shells, the artefact on the Enzo snapshot). Gas colder than about 300 K glows at 0 K
    /// (nothing in any visible band either way). Thermal line broadening keeps the
    /// trilinearly interpolated temperature.
    ///
    /// Bricked density and temperature (same layout) get bricked emission, computed brick by
    /// brick through their cache with the same per-voxel arithmetic.
    pub fn set_blackbody(
        &mut self,
        density: impl Into<Field>,
        temperature_k: impl Into<Field>,
    ) -> Result<()> {
        let (density, temperature_k) = (density.into(), temperature_k.into());
        scalar("black-body density", &density)?;
        scalar("temperature", &temperature_k)?;
        check_geometry("black-body density", density.geometry(), &self.geometry)?;
        check_geometry("temperature", temperature_k.geometry(), &self.geometry)?;
        let emission =
            |d: f32, t: f32| (f64::from(d.max(0.0)) * planck_factor(f64::from(t))) as f32;
        self.rho_t = Some(match (&density, &temperature_k) {
            (Field::Dense(dg), Field::Dense(tg)) => {
                let (d, t) = (dg.to_f32_vec(), tg.to_f32_vec());
                Field::from(Grid::from_fn(self.geometry, |x, y, z| {
                    let i = self.geometry.index(x, y, z);
                    emission(d[i], t[i])
                })?)
            }
            (Field::Bricked(d), Field::Bricked(t)) => {
                blueshift_volume::field::CombinedSource::new(d, t, emission)
                    .map_err(|e| Error::scene(format!("black body: density and temperature: {e}")))?
                    .field()?
                    .into()
            }
            _ => {
                return Err(Error::scene(
                    "black body: the density and the temperature must both be in memory or both \
                     bricked (.bsv)",
                ));
            }
        });
        self.blackbody = Some((density, temperature_k));
        Ok(())
    }

    /// Black-body density times [`planck_factor`] per voxel: what the renderers interpolate
    /// for the temperature between voxels (see [`DopplerScene::set_blackbody`]).
    #[must_use]
    pub fn blackbody_rho_t(&self) -> Option<&Field> {
        self.rho_t.as_ref()
    }

    /// The velocity field, m/s.
    pub fn set_velocity(&mut self, velocity_m_per_s: impl Into<VectorField>) -> Result<()> {
        let velocity_m_per_s = velocity_m_per_s.into();
        check_geometry("velocity", velocity_m_per_s.geometry(), &self.geometry)?;
        let finite = match &velocity_m_per_s {
            VectorField::Dense(g) => g.data().iter().all(|v| v.is_finite()),
            VectorField::Components(c) => c.iter().all(|f| f.reject_non_finite().is_ok()),
        };
        if !finite {
            return Err(Error::scene("velocity has non-finite values"));
        }
        self.velocity = Some(velocity_m_per_s);
        Ok(())
    }

    /// Every field of the scene, scalar ones first, then the velocity's components.
    #[must_use]
    pub fn fields(&self) -> Vec<&Field> {
        let mut v: Vec<&Field> = self.species.iter().map(|s| &s.density).collect();
        if let Some((d, t)) = &self.blackbody {
            v.extend([d, t]);
        }
        v.extend(self.rho_t.iter());
        if let Some(VectorField::Components(c)) = &self.velocity {
            v.extend(c.iter());
        }
        v
    }

    /// Geometries of the levels of detail, finest first, when every field is bricked
    /// alike (`None` for a scene with a field in memory: it has one level).
    #[must_use]
    pub fn levels(&self) -> Option<Vec<Geometry>> {
        let fields = self.fields();
        if matches!(self.velocity, Some(VectorField::Dense(_))) {
            return None;
        }
        let first = fields.first()?.as_bricked()?;
        let geoms = first.source().geometries().to_vec();
        fields
            .iter()
            .all(|f| {
                f.as_bricked()
                    .is_some_and(|b| b.source().geometries() == geoms)
            })
            .then_some(geoms)
    }

    /// The same scene with a level of detail per brick of every bricked field
    /// ([`blueshift_volume::BrickedField::per_region`]): `pick(lo, hi)` is the level for a
    /// brick's world box. Every field must be bricked alike ([`DopplerScene::levels`]).
    pub fn per_brick(&self, pick: impl Fn(Vec3, Vec3) -> usize) -> Result<DopplerScene> {
        self.map_bricked(|b| Ok(b.per_region(&pick)?))
    }

    /// The same scene with every bricked field sampled, region by region (one brick of its
    /// level each), at the finest level its cache holds there now
    /// ([`blueshift_volume::BrickedField::resident_regions`]): the view of a progressive
    /// render while bricks load. Returns the scene and, summed over the fields, the regions
    /// at the fields' own level and all regions.
    ///
    /// # Errors
    /// A field in memory (every field must be bricked alike, [`DopplerScene::levels`]).
    pub fn resident_view(&self) -> Result<(DopplerScene, usize, usize)> {
        let counts = std::cell::Cell::new((0, 0));
        let view = self.map_bricked(|b| {
            let (f, at) = b.resident_regions()?;
            let (a, n) = counts.get();
            counts.set((a + at, n + b.brick_counts().iter().product::<usize>()));
            Ok(f)
        })?;
        let (at, regions) = counts.get();
        Ok((view, at, regions))
    }

    /// The same scene with every field sampling one level per region, the coarsest any
    /// field samples there ([`blueshift_volume::shared_region_levels`]): a view one GPU
    /// pool lookup serves (per-field resident views differ while bricks load).
    ///
    /// # Errors
    /// A field in memory (every field must be bricked alike, [`DopplerScene::levels`]).
    pub fn shared_regions(&self) -> Result<DopplerScene> {
        let fields: Vec<&blueshift_volume::BrickedField> = self
            .fields()
            .into_iter()
            .filter_map(Field::as_bricked)
            .collect();
        let shared = blueshift_volume::shared_region_levels(&fields)?;
        // map_bricked visits the fields in `fields()` order.
        let next = std::cell::Cell::new(0usize);
        self.map_bricked(|_| {
            let i = next.get();
            next.set(i + 1);
            shared
                .get(i)
                .cloned()
                .ok_or_else(|| Error::parameter("a field in memory"))
        })
    }

    /// The same scene with every field's per-region levels of detail (`--lod brick`) `k`
    /// levels coarser, clamped to the coarsest
    /// ([`blueshift_volume::BrickedField::coarser_regions`]): what a GPU pool too small for
    /// the per-brick view falls back on. The second value says whether any region is coarser
    /// than with `k - 1`.
    ///
    /// # Errors
    /// A field in memory (every field must be bricked alike, [`DopplerScene::levels`]).
    pub fn coarser_regions(&self, k: usize) -> Result<(DopplerScene, bool)> {
        let moved = std::cell::Cell::new(false);
        let s = self.map_bricked(|b| {
            let (f, m) = b.coarser_regions(k)?;
            moved.set(moved.get() | m);
            Ok(f)
        })?;
        Ok((s, moved.get()))
    }

    /// This scene with every bricked field replaced by `f` of it (every field bricked alike).
    fn map_bricked(
        &self,
        f: impl Fn(&blueshift_volume::BrickedField) -> Result<blueshift_volume::BrickedField>,
    ) -> Result<DopplerScene> {
        self.levels().ok_or_else(|| {
            Error::parameter("levels of detail need every field bricked (.bsv) alike")
        })?;
        let map = |x: &Field| -> Result<Field> {
            Ok(f(x.as_bricked().expect("levels() checked"))?.into())
        };
        let mut out = self.clone();
        for s in &mut out.species {
            s.density = map(&s.density)?;
        }
        if let Some((d, t)) = &mut out.blackbody {
            *d = map(d)?;
            *t = map(t)?;
        }
        if let Some(r) = &mut out.rho_t {
            *r = map(r)?;
        }
        if let Some(VectorField::Components(c)) = &mut out.velocity {
            for x in c.iter_mut() {
                *x = map(x)?;
            }
        }
        Ok(out)
    }

    /// The same scene sampled at level of detail `level` of its bricked fields (see
    /// [`DopplerScene::levels`]; level 0 is this scene).
    pub fn at_level(&self, level: usize) -> Result<DopplerScene> {
        if level == 0 {
            return Ok(self.clone());
        }
        let geoms = self.levels().ok_or_else(|| {
            Error::parameter("levels of detail need every field bricked (.bsv) alike")
        })?;
        let g = *geoms
            .get(level)
            .ok_or_else(|| Error::parameter(format!("level {level} of {} levels", geoms.len())))?;
        let mut out = self.map_bricked(|b| Ok(b.at_level(level)?))?;
        out.geometry = g;
        Ok(out)
    }

    /// The first brick read that failed while rendering (bricked fields), as an error.
    pub fn check_io(&self) -> Result<()> {
        for s in &self.species {
            s.density.check_io()?;
        }
        if let Some((d, t)) = &self.blackbody {
            d.check_io()?;
            t.check_io()?;
        }
        if let Some(r) = &self.rho_t {
            r.check_io()?;
        }
        if let Some(v) = &self.velocity {
            v.check_io()?;
        }
        Ok(())
    }

    /// Subtracts the mean velocity (the bulk motion), so the Doppler shifts show motion
    /// relative to the gas as a whole. Components given as separate fields (`.bsv` files)
    /// are averaged in one streaming pass each and shifted brick by brick as they are read
    /// (derived bricks: nothing is loaded whole), with the same f32 subtraction as a dense
    /// field.
    ///
    /// # Errors
    /// A brick that cannot be read while averaging.
    pub fn subtract_mean_velocity(&mut self) -> Result<()> {
        match &mut self.velocity {
            Some(VectorField::Dense(v)) => {
                let n = v.data().len().max(1) as f64;
                let mut sum = [0.0f64; 3];
                for x in v.data() {
                    sum[0] += f64::from(x.x);
                    sum[1] += f64::from(x.y);
                    sum[2] += f64::from(x.z);
                }
                let mean = Vec3::new(
                    (sum[0] / n) as f32,
                    (sum[1] / n) as f32,
                    (sum[2] / n) as f32,
                );
                for x in v.data_mut() {
                    *x -= mean;
                }
            }
            Some(VectorField::Components(c)) => {
                for f in c.iter_mut() {
                    let m = f.mean()? as f32;
                    *f = match &*f {
                        Field::Bricked(b) => Field::from(
                            blueshift_volume::field::CombinedSource::monotone(b, move |v| v - m)
                                .field()?,
                        ),
                        Field::Dense(g) => {
                            let data = g.to_f32_vec().into_iter().map(|v| v - m).collect();
                            Field::from(AnyGrid::F32(Grid::from_vec(*g.geometry(), data)?))
                        }
                    };
                }
            }
            None => {}
        }
        Ok(())
    }

    /// A scene from a volume with the synthetic datasets' channel names: species tokens `bb`
    /// (black body: `hi_density` x `temperature_k`), `H` (`hi_density`, H I Balmer), `He`
    /// (`he_density`, He I), `C` (`c_density`, C I). Emission lines double as absorption
    /// lines (scaled by [`Factors::absorption`]). The velocity is `velocity_m_per_s` if present.
    pub fn from_volume(volume: &Volume, tokens: &[&str]) -> Result<Self> {
        let mut scene = Self::new(*volume.geometry())?;
        if tokens.is_empty() {
            return Err(Error::parameter("no species given"));
        }
        let need = |name: &str| -> Result<Field> {
            volume
                .channel(name)
                .map(|c| Field::from(c.grid.clone()))
                .ok_or_else(|| Error::scene(format!("the volume has no channel '{name}'")))
        };
        for t in tokens {
            let t = t.trim();
            if t.eq_ignore_ascii_case("bb") || t.eq_ignore_ascii_case("blackbody") {
                scene.set_blackbody(need("hi_density")?, need("temperature_k")?)?;
                continue;
            }
            let cat = Catalogue::parse(t).map_err(|e| Error::parameter(e.to_string()))?;
            let channel = match cat {
                Catalogue::HydrogenBalmer => "hi_density",
                Catalogue::HeliumI => "he_density",
                Catalogue::CarbonI => "c_density",
            };
            let lines = cat.lines();
            scene.add_species(Species {
                name: cat.short_name().to_owned(),
                density: need(channel)?,
                emission_lines: lines.clone(),
                absorption_lines: lines,
            })?;
        }
        if let Some(c) = volume.channel("velocity_m_per_s") {
            match &c.grid {
                AnyGrid::Vec3(g) => scene.set_velocity(g.clone())?,
                _ => return Err(Error::scene("velocity_m_per_s must be a vector channel")),
            }
        }
        Ok(scene)
    }
}
