//! Scenes: N scalar channels sharing one geometry, each with its own transfer function and
//! majorant grid, a background colour, a density scale and an optional directional light.

use blueshift_camera::ClipBox;
use blueshift_tfedit::TransferFunction;
use blueshift_volume::{Field, Geometry, Macrocells, Volume};
use glam::Vec3;

use crate::dda::CellLayout;
use crate::majorant::MajorantGrid;
use crate::shading::Shading;
use crate::{Error, Result};

/// One channel of a [`Scene`]: a scalar field (dense or bricked), its transfer function,
/// its macrocells and the majorant grid derived from both.
#[derive(Clone, Debug)]
pub struct SceneChannel {
    name: String,
    grid: Field,
    tf: TransferFunction,
    macrocells: Macrocells,
    majorant: MajorantGrid,
}

impl SceneChannel {
    /// Channel name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The scalar field (a dense grid or a level of a bricked file).
    #[must_use]
    pub fn grid(&self) -> &Field {
        &self.grid
    }
    /// The transfer function.
    #[must_use]
    pub fn transfer_function(&self) -> &TransferFunction {
        &self.tf
    }
    /// The macrocells (value ranges) of the grid.
    #[must_use]
    pub fn macrocells(&self) -> &Macrocells {
        &self.macrocells
    }
    /// The majorant grid (extinction per unit world length).
    #[must_use]
    pub fn majorant(&self) -> &MajorantGrid {
        &self.majorant
    }
}

/// A directional light for volumetric shadows: radiance arriving from `direction`
/// (pointing from the volume towards the light), attenuated by the volume's transmittance,
/// plus an unshadowed ambient term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionalLight {
    /// Direction towards the light (normalised when used).
    pub direction: Vec3,
    /// Radiance of the light per RGB channel (linear, no unit beyond the colour map's).
    pub radiance: [f32; 3],
    /// Ambient light added without shadowing (0 = light only).
    pub ambient: f32,
}

/// A scene of N channels sharing one geometry.
///
/// Extinction per unit world length of channel n at a point is
/// `sigma_n = tf_n.eval(value)[3] * density_scale` (the opacity, which already includes the
/// transfer function's alpha_g, times the density scale); its emitted colour is the transfer
/// function's RGB. Every method (Woodcock, MDWT, marcher) uses this same definition, so
/// their images can be compared for the same density scale.
#[derive(Clone, Debug)]
pub struct Scene {
    channels: Vec<SceneChannel>,
    /// World bounds of the finest level (what cameras frame and rays are clipped to at
    /// every level).
    frame: (Vec3, Vec3),
    /// The finest level's geometry (the scene's own in core).
    finest: Geometry,
    layout: CellLayout,
    total_majorant: MajorantGrid,
    density_scale: f32,
    /// Colour seen where the ray leaves the volume, weighted by its transmittance.
    pub background: [f32; 3],
    /// Optional light; `None` means emission only (the collision colour is returned as is).
    pub light: Option<DirectionalLight>,
    /// Gradient shading at real collisions (`None`, the default: emission-absorption).
    pub shading: Option<Shading>,
    /// Render only the samples inside this box (`None`, the default: all), for sort-last
    /// distributed rendering (`blueshift-dist`): the ray marcher keeps its global sample
    /// positions (steps from the ray's entry into the whole volume) and takes the samples
    /// that fall inside, so the partial images of boxes that tile space composite to the
    /// whole render. Only the ray marcher supports it ([`Integrator::prepared`] refuses the
    /// trackers), and it renders with a transparent background (alpha is returned).
    ///
    /// [`Integrator::prepared`]: crate::Integrator::prepared
    pub clip: Option<ClipBox>,
}

impl Scene {
    /// Builds a scene from `(name, field, transfer function)` triples (dense grids or levels
    /// of bricked files, see [`Field`]) with macrocells of `k` voxels per edge. Refuses an
    /// empty list, vector grids, channels whose geometry differs from the first, and a
    /// negative or non-finite density scale.
    pub fn new<F: Into<Field>>(
        channels: Vec<(String, F, TransferFunction)>,
        density_scale: f32,
        k: usize,
    ) -> Result<Self> {
        if channels.is_empty() {
            return Err(Error::scene("channels: at least one channel is needed"));
        }
        check_density_scale(density_scale)?;
        let channels: Vec<(String, Field, TransferFunction)> = channels
            .into_iter()
            .map(|(n, g, t)| (n, g.into(), t))
            .collect();
        let geometry = *channels[0].1.geometry();
        let finest = *channels[0].1.finest_geometry();
        let frame = finest.world_bounds();
        geometry.validate()?;
        let mut out = Vec::with_capacity(channels.len());
        for (i, (name, grid, tf)) in channels.into_iter().enumerate() {
            if grid.is_vector() {
                return Err(Error::scene(format!(
                    "channels[{i}] ('{name}'): vector channels cannot be rendered; pick a scalar"
                )));
            }
            if *grid.geometry() != geometry {
                return Err(Error::scene(format!(
                    "channels[{i}] ('{name}'): geometry {} differs from channel 0's {}",
                    describe(grid.geometry()),
                    describe(&geometry)
                )));
            }
            let macrocells = grid.macrocells(k)?;
            let majorant = MajorantGrid::build(&macrocells, &tf, density_scale).framed(&finest);
            out.push(SceneChannel {
                name,
                grid,
                tf,
                macrocells,
                majorant,
            });
        }
        let layout = CellLayout::of(&out[0].macrocells).framed(&finest);
        let total_majorant = total(&out);
        check_optical_depth(&total_majorant, &geometry)?;
        Ok(Scene {
            channels: out,
            frame,
            finest,
            layout,
            total_majorant,
            density_scale,
            background: [0.0; 3],
            light: None,
            shading: None,
            clip: None,
        })
    }

    /// A scene from a volume's scalar channels (in order), one transfer function each.
    pub fn from_volume(
        volume: &Volume,
        tfs: Vec<TransferFunction>,
        density_scale: f32,
        k: usize,
    ) -> Result<Self> {
        let chans = volume.channels();
        if chans.len() != tfs.len() {
            return Err(Error::scene(format!(
                "tfs: {} transfer functions for {} channels",
                tfs.len(),
                chans.len()
            )));
        }
        let triples = chans
            .iter()
            .zip(tfs)
            .map(|(c, tf)| (c.name.clone(), c.grid.clone(), tf))
            .collect();
        Scene::new(triples, density_scale, k)
    }

    /// Replaces channel `i`'s transfer function and rebuilds its majorant grid (in parallel).
    pub fn set_transfer_function(&mut self, i: usize, tf: TransferFunction) -> Result<()> {
        let n = self.channels.len();
        let ch = self
            .channels
            .get_mut(i)
            .ok_or_else(|| Error::parameter(format!("channel {i} out of range (0..{n})")))?;
        ch.majorant =
            MajorantGrid::build(&ch.macrocells, &tf, self.density_scale).framed(&self.finest);
        ch.tf = tf;
        self.total_majorant = total(&self.channels);
        Ok(())
    }

    /// Changes the density scale and rebuilds all majorant grids.
    pub fn set_density_scale(&mut self, density_scale: f32) -> Result<()> {
        check_density_scale(density_scale)?;
        self.density_scale = density_scale;
        for ch in &mut self.channels {
            ch.majorant =
                MajorantGrid::build(&ch.macrocells, &ch.tf, density_scale).framed(&self.finest);
        }
        self.total_majorant = total(&self.channels);
        check_optical_depth(&self.total_majorant, &self.layout.geometry)
    }

    /// The channels.
    #[must_use]
    pub fn channels(&self) -> &[SceneChannel] {
        &self.channels
    }

    /// Number of channels.
    #[must_use]
    pub fn channel_count(&self) -> usize {
        self.channels.len()
    }

    /// The shared voxel geometry.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.layout.geometry
    }

    /// The macrocell layout shared by all majorant grids.
    #[must_use]
    pub fn layout(&self) -> &CellLayout {
        &self.layout
    }

    /// World bounds of the finest level's voxel centres: what cameras frame, so every
    /// level of detail is seen through the same view (equal to [`Scene::bounds`] in core).
    #[must_use]
    pub fn frame_bounds(&self) -> (Vec3, Vec3) {
        self.frame
    }

    /// The level every channel samples and the number of levels every channel has alike,
    /// when all channels are the same level of bricked sources (`None` in core). Files of
    /// the same volume in different brick edges share their finer levels (a pyramid stops
    /// at one brick, so smaller bricks go further): those count.
    #[must_use]
    pub fn lod(&self) -> Option<(usize, usize)> {
        let first = self.channels.first()?.grid.as_bricked()?;
        let geoms = first.source().geometries();
        let mut count = geoms.len();
        for c in &self.channels {
            let b = c.grid.as_bricked()?;
            if b.level() != first.level() {
                return None;
            }
            count = count.min(common_levels(b.source().geometries(), geoms));
        }
        (first.level() < count).then_some((first.level(), count))
    }

    /// The same scene (transfer functions, density scale, light, shading, background, the
    /// macrocell edge) with every channel at level `level` of its bricked source (0: the
    /// finest); see [`Scene::lod`].
    ///
    /// # Errors
    /// A channel in memory, or a level past the coarsest.
    pub fn at_level(&self, level: usize) -> Result<Scene> {
        self.with_bricked(|b| Ok(Field::from(b.at_level(level)?)))
    }

    /// The same scene (transfer functions, frame, background, light, shading, clip) with
    /// each channel's field replaced by `field` of its bricked field.
    ///
    /// # Errors
    /// A channel in memory; `field`'s error; as [`Scene::new`].
    fn with_bricked(
        &self,
        mut field: impl FnMut(&blueshift_volume::BrickedField) -> Result<Field>,
    ) -> Result<Scene> {
        let k = self.channels[0].macrocells.k();
        let mut chans = Vec::with_capacity(self.channels.len());
        for (i, c) in self.channels.iter().enumerate() {
            let b = c.grid.as_bricked().ok_or_else(|| {
                Error::scene(format!(
                    "channels[{i}] ('{}'): levels of detail need every channel bricked (.bsv)",
                    c.name
                ))
            })?;
            chans.push((c.name.clone(), field(b)?, c.tf.clone()));
        }
        let mut s = Scene::new(chans, self.density_scale, k)?;
        debug_assert_eq!(s.frame, self.frame, "every level frames the finest box");
        s.background = self.background;
        s.light = self.light;
        s.shading = self.shading.clone();
        s.clip = self.clip;
        Ok(s)
    }

    /// The same scene with every channel sampled, region by region (one brick of its level
    /// each), at the finest level its cache holds there now
    /// ([`blueshift_volume::BrickedField::resident_regions`]): the view of a progressive
    /// render while bricks load. Returns the scene and, summed over the channels, the regions
    /// at the scene's own level and all regions.
    ///
    /// # Errors
    /// A channel in memory; as [`Scene::new`].
    pub fn resident_view(&self) -> Result<(Scene, usize, usize)> {
        let (mut at_base, mut regions) = (0, 0);
        let s = self.with_bricked(|b| {
            let (f, n) = b.resident_regions()?;
            at_base += n;
            regions += b.brick_counts().iter().product::<usize>();
            Ok(Field::from(f))
        })?;
        Ok((s, at_base, regions))
    }

    /// The same scene with every channel sampling one level per region, the coarsest any
    /// channel samples there ([`blueshift_volume::shared_region_levels`]): a view one GPU
    /// pool lookup serves (per-channel resident views differ while bricks load).
    ///
    /// # Errors
    /// A channel in memory; as [`Scene::new`].
    pub fn shared_regions(&self) -> Result<Scene> {
        let fields: Vec<&blueshift_volume::BrickedField> = self
            .channels
            .iter()
            .filter_map(|c| c.grid.as_bricked())
            .collect();
        let mut shared = blueshift_volume::shared_region_levels(&fields)?.into_iter();
        self.with_bricked(|_| {
            shared
                .next()
                .map(Field::from)
                .ok_or_else(|| Error::scene("a channel in memory"))
        })
    }

    /// The coarsest level any channel's samples read (per-region levels included), or
    /// `None` when no channel is bricked.
    #[must_use]
    pub fn coarsest_sampled_level(&self) -> Option<usize> {
        self.channels
            .iter()
            .filter_map(|c| c.grid.as_bricked())
            .map(blueshift_volume::BrickedField::coarsest_sampled_level)
            .max()
    }

    /// The same scene with every bricked channel's per-region levels of detail (`--lod
    /// brick`) `k` levels coarser, clamped to the coarsest
    /// ([`blueshift_volume::BrickedField::coarser_regions`]): what a GPU pool too small for
    /// the per-brick view falls back on. The second value says whether any region is coarser
    /// than with `k - 1`.
    ///
    /// # Errors
    /// A channel in memory; as [`Scene::new`].
    pub fn coarser_regions(&self, k: usize) -> Result<(Scene, bool)> {
        let mut moved = false;
        let s = self.with_bricked(|b| {
            let (f, m) = b.coarser_regions(k)?;
            moved |= m;
            Ok(Field::from(f))
        })?;
        Ok((s, moved))
    }

    /// The first brick read that failed while rendering (out-of-core channels), as an
    /// error; renders call this after every pass.
    pub fn check_io(&self) -> Result<()> {
        for c in &self.channels {
            c.grid.check_io()?;
        }
        Ok(())
    }

    /// World bounds `(min, max)` rays are clipped to: the voxel centres' box of the finest
    /// level ([`Scene::frame_bounds`]), so every level of detail covers the same box (a
    /// coarser level's own voxel centres lie up to half a coarse voxel inside it; samples
    /// there clamp to the edge voxels).
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.frame
    }

    /// The density scale: extinction per unit world length = opacity x density scale.
    #[must_use]
    pub fn density_scale(&self) -> f32 {
        self.density_scale
    }

    /// Cell-wise sum of all channels' majorants (bounds the total extinction of every blend).
    #[must_use]
    pub fn total_majorant(&self) -> &MajorantGrid {
        &self.total_majorant
    }

    /// Extinction (per unit world length) and emitted colour of channel `n` at world point `p`
    /// (trilinear sample, clamped to the grid). Panics if `n >= channel_count()`, like
    /// slice indexing.
    #[inline]
    #[must_use]
    pub fn sample(&self, n: usize, p: Vec3) -> (f32, [f32; 3]) {
        let ch = &self.channels[n];
        let v = ch
            .grid
            .sample_scalar_index(self.layout.geometry.world_to_index(p));
        let [r, g, b, a] = ch.tf.eval(f64::from(v));
        (a * self.density_scale, [r, g, b])
    }
}

/// Checks a light: a finite non-zero direction, finite non-negative radiance and ambient.
pub(crate) fn check_light(l: &DirectionalLight) -> Result<()> {
    if !l.direction.is_finite() || l.direction.try_normalize().is_none() {
        return Err(Error::parameter(format!(
            "light.direction: {:?} must be a finite non-zero vector",
            l.direction
        )));
    }
    if !l.radiance.iter().all(|v| v.is_finite() && *v >= 0.0) {
        return Err(Error::parameter(format!(
            "light.radiance: {:?} must be finite and non-negative",
            l.radiance
        )));
    }
    if !(l.ambient.is_finite() && l.ambient >= 0.0) {
        return Err(Error::parameter(format!(
            "light.ambient: {} must be finite and non-negative",
            l.ambient
        )));
    }
    Ok(())
}

fn check_density_scale(s: f32) -> Result<()> {
    if !(s >= 0.0 && s.is_finite()) {
        return Err(Error::scene(format!(
            "density_scale: {s} must be finite and non-negative"
        )));
    }
    Ok(())
}

/// Largest majorant optical depth across the volume's diagonal that a scene may have. Beyond
/// it the volume is opaque to any precision, and tracking would take absurdly many steps.
pub const MAX_OPTICAL_DEPTH: f32 = 1e6;

fn check_optical_depth(total: &MajorantGrid, g: &Geometry) -> Result<()> {
    let (lo, hi) = g.world_bounds();
    // In f64: the squared diagonal of a volume in centimetres (1e21 per voxel) overflows f32.
    let diag = (hi - lo)
        .as_dvec3()
        .length()
        .max(f64::from(g.spacing.min_element()));
    let max = total.values().iter().copied().fold(0.0f32, f32::max);
    let depth = f64::from(max) * diag;
    if !depth.is_finite() || depth > f64::from(MAX_OPTICAL_DEPTH) {
        return Err(Error::scene(format!(
            "density_scale: the largest extinction {max} per unit length over the volume's \
             diagonal {diag} is an optical depth of {depth}, above {MAX_OPTICAL_DEPTH}; \
             lower the density scale"
        )));
    }
    Ok(())
}

fn total(chs: &[SceneChannel]) -> MajorantGrid {
    let grids: Vec<&MajorantGrid> = chs.iter().map(|c| &c.majorant).collect();
    MajorantGrid::combined(&grids, |a, b| a + b)
}

/// How many levels, from the finest, two pyramids have alike.
#[must_use]
pub fn common_levels(a: &[Geometry], b: &[Geometry]) -> usize {
    a.iter().zip(b).take_while(|(x, y)| x == y).count()
}

/// A geometry for a message: `16x16x16 voxels, spacing [1, 1, 1], origin [0, 0, 0]`.
fn describe(g: &Geometry) -> String {
    let [x, y, z] = g.dims;
    format!(
        "{x}x{y}x{z} voxels, spacing {}, origin {}",
        g.spacing, g.origin
    )
}
