//! Deterministic synthetic datasets: the same `(res, seed)` gives the same voxels on any
//! machine and thread count (voxels are pure functions of their index; noise is a hashed
//! lattice, no shared random state).
//!
//! | name | function | channels |
//! |---|---|---|
//! | `galaxy` | [`galaxy`] | `hi_density`, `he_density`, `c_density`, `dust_density`, `temperature_k`, `velocity_m_per_s` |
//! | `hydrogen-shell` | [`hydrogen_shell`] | `hi_density`, `velocity_m_per_s` |
//! | `three-cubes` | [`three_cubes`] | `red`, `green`, `blue` |
//! | `turbulence` | [`turbulence`] | `density` |
//! | `marschner-lobb` | [`marschner_lobb`] | `density` |
//! | `channels12` | [`channels12`] | `c00` ... `c11` |

use glam::Vec3;

use crate::grid::{Geometry, Grid};
use crate::ooc::MultiSlabSource;
use crate::volume::Volume;
use crate::{Error, Result};

type VoxelFn = dyn Fn([usize; 3], &mut [f32]) + Send + Sync;

/// A dataset as one pure function of the voxel index that gives every channel's values (a
/// vector channel as three consecutive components), so it can be computed slice by slice
/// straight into bricked files of any size ([`crate::ooc::convert_many`], through
/// [`MultiSlabSource`]) or into memory ([`Stream::to_volume`]), with the same voxels.
pub struct Stream {
    geometry: Geometry,
    channels: Vec<(String, usize)>,
    voxel: Box<VoxelFn>,
    /// Which components [`MultiSlabSource`] gives (all by default).
    selected: Vec<usize>,
}

impl std::fmt::Debug for Stream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stream")
            .field("geometry", &self.geometry)
            .field("channels", &self.channels)
            .field("selected", &self.selected)
            .finish_non_exhaustive()
    }
}

impl Stream {
    fn new(
        geometry: Geometry,
        channels: &[(&str, usize)],
        voxel: impl Fn([usize; 3], &mut [f32]) + Send + Sync + 'static,
    ) -> Result<Self> {
        geometry.validate()?;
        let channels: Vec<(String, usize)> =
            channels.iter().map(|&(n, c)| (n.to_string(), c)).collect();
        let n: usize = channels.iter().map(|c| c.1).sum();
        Ok(Stream {
            geometry,
            channels,
            voxel: Box::new(voxel),
            selected: (0..n).collect(),
        })
    }

    /// The grid geometry.
    #[must_use]
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }

    /// Channel names with their component counts (1: scalar, 3: vector).
    #[must_use]
    pub fn channels(&self) -> &[(String, usize)] {
        &self.channels
    }

    /// Every scalar component's name: a scalar channel's own, a vector's as `name_x`,
    /// `name_y`, `name_z`.
    #[must_use]
    pub fn component_names(&self) -> Vec<String> {
        self.channels
            .iter()
            .flat_map(|(n, c)| {
                if *c == 1 {
                    vec![n.clone()]
                } else {
                    ["x", "y", "z"].iter().map(|a| format!("{n}_{a}")).collect()
                }
            })
            .collect()
    }

    /// Gives only channel `name` (all its components) through [`MultiSlabSource`].
    ///
    /// # Errors
    /// No channel of that name.
    pub fn select(&mut self, name: &str) -> Result<()> {
        let mut first = 0;
        for (n, c) in &self.channels {
            if n == name {
                self.selected = (first..first + c).collect();
                return Ok(());
            }
            first += c;
        }
        let names: Vec<&str> = self.channels.iter().map(|c| c.0.as_str()).collect();
        Err(Error::parameter(format!(
            "no channel '{name}' (channels: {})",
            names.join(", ")
        )))
    }

    /// Names of the components [`MultiSlabSource`] gives.
    #[must_use]
    pub fn selected_names(&self) -> Vec<String> {
        let all = self.component_names();
        self.selected.iter().map(|&i| all[i].clone()).collect()
    }

    /// Fills `out[c]` (`dims.x * dims.y` values each, one per component) with slice `z`,
    /// rows in parallel.
    fn fill_slice(&self, z: usize, selected: &[usize], out: &mut [Vec<f32>]) {
        use rayon::prelude::*;
        let [nx, ny, _] = self.geometry.dims;
        let nc: usize = self.channels.iter().map(|c| c.1).sum();
        let rows: Vec<Vec<f32>> = (0..ny)
            .into_par_iter()
            .map(|y| {
                let mut r = vec![0f32; nx * nc];
                for (x, v) in r.chunks_exact_mut(nc).enumerate() {
                    (self.voxel)([x, y, z], v);
                }
                r
            })
            .collect();
        for (o, &c) in out.iter_mut().zip(selected) {
            o.resize(nx * ny, 0.0);
            for (y, r) in rows.iter().enumerate() {
                for (x, d) in o[y * nx..(y + 1) * nx].iter_mut().enumerate() {
                    *d = r[x * nc + c];
                }
            }
        }
    }

    /// Bytes [`Stream::to_volume`] holds at its peak: every component as `f32`, plus a
    /// vector channel's `Vec3` grid while it is assembled (saturating).
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        let dims = self.geometry.dims;
        self.channels.iter().fold(0u64, |acc, (_, c)| {
            let per = if *c == 1 { 4 } else { 4 * c + 12 };
            acc.saturating_add(crate::budget::grid_bytes(dims, per, 1))
        })
    }

    /// [`Stream::to_volume`] after checking [`Stream::memory_bytes`] against `budget`.
    ///
    /// # Errors
    /// [`Error::Budget`] before anything is allocated; as [`Stream::to_volume`].
    pub fn to_volume_within(&self, budget: &crate::MemoryBudget) -> Result<Volume> {
        let [nx, ny, nz] = self.geometry.dims;
        let comps: usize = self.channels.iter().map(|c| c.1).sum();
        budget.check(
            format_args!("this dataset ({nx}x{ny}x{nz} voxels, {comps} f32 components)"),
            self.memory_bytes(),
        )?;
        self.to_volume()
    }

    /// Computes every channel in memory.
    ///
    /// # Errors
    /// A grid too large to allocate.
    pub fn to_volume(&self) -> Result<Volume> {
        let g = self.geometry;
        let [nx, ny, nz] = g.dims;
        let nc: usize = self.channels.iter().map(|c| c.1).sum();
        let all: Vec<usize> = (0..nc).collect();
        let mut data: Vec<Vec<f32>> = Vec::with_capacity(nc);
        for _ in 0..nc {
            let mut v = Vec::new();
            v.try_reserve_exact(g.voxel_count())
                .map_err(|_| Error::Limits(format!("cannot allocate a {nx}x{ny}x{nz} grid")))?;
            data.push(v);
        }
        let mut slice = vec![Vec::new(); nc];
        for z in 0..nz {
            self.fill_slice(z, &all, &mut slice);
            for (d, s) in data.iter_mut().zip(&slice) {
                d.extend_from_slice(s);
            }
        }
        let mut vol = Volume::new(g)?;
        let mut comps = data.into_iter();
        for (name, c) in &self.channels {
            if *c == 1 {
                vol.push(
                    name.clone(),
                    Grid::from_vec(g, comps.next().expect("component"))?,
                )?;
            } else {
                let (x, y, z) = (
                    comps.next().expect("x"),
                    comps.next().expect("y"),
                    comps.next().expect("z"),
                );
                let v: Vec<Vec3> = x
                    .iter()
                    .zip(&y)
                    .zip(&z)
                    .map(|((&a, &b), &c)| Vec3::new(a, b, c))
                    .collect();
                vol.push(name.clone(), Grid::from_vec(g, v)?)?;
            }
        }
        Ok(vol)
    }
}

impl MultiSlabSource for Stream {
    fn geometry(&self) -> Geometry {
        self.geometry
    }
    fn channels(&self) -> usize {
        self.selected.len()
    }
    fn read_slices(&mut self, z: usize, out: &mut [Vec<f32>]) -> Result<()> {
        self.fill_slice(z, &self.selected, out);
        Ok(())
    }
}

/// Names accepted by [`by_name`].
pub const NAMES: &[&str] = &[
    "galaxy",
    "hydrogen-shell",
    "three-cubes",
    "turbulence",
    "marschner-lobb",
    "channels12",
];

/// Builds the dataset called `name` (see [`NAMES`]) at `res` voxels per edge.
pub fn by_name(name: &str, res: usize, seed: u64) -> Result<Volume> {
    stream_by_name(name, res, seed)?.to_volume()
}

/// [`by_name`], its memory estimate checked against `budget` before anything is allocated.
///
/// # Errors
/// [`Error::Budget`]; as [`by_name`].
pub fn by_name_within(
    name: &str,
    res: usize,
    seed: u64,
    budget: &crate::MemoryBudget,
) -> Result<Volume> {
    check_res(res)?;
    let dims = dims_of(name, res);
    let needed = memory_bytes(name, res)?;
    budget.check(
        format_args!(
            "this dataset ({name}, {}x{}x{} voxels, f32)",
            dims[0], dims[1], dims[2]
        ),
        needed,
    )?;
    stream_by_name(name, res, seed)?.to_volume()
}

/// The voxel counts of dataset `name` at resolution `res`.
fn dims_of(name: &str, res: usize) -> [usize; 3] {
    if name == "galaxy" {
        [res, res, (res / 2).max(2)]
    } else {
        [res; 3]
    }
}

/// The bytes [`by_name`] holds at its peak for `name` at `res` ([`Stream::memory_bytes`]),
/// computed without building the dataset (some streams scan the grid when they are made).
///
/// # Errors
/// An unknown dataset or a bad resolution.
pub fn memory_bytes(name: &str, res: usize) -> Result<u64> {
    check_res(res)?;
    let tiny = stream_by_name(name, 2, 1)?;
    let per_voxel = tiny.memory_bytes() / tiny.geometry().voxel_count() as u64;
    Ok(crate::budget::grid_bytes(dims_of(name, res), 1, 1).saturating_mul(per_voxel))
}

/// The dataset called `name` as a [`Stream`], computed slice by slice when read.
pub fn stream_by_name(name: &str, res: usize, seed: u64) -> Result<Stream> {
    match name {
        "galaxy" => galaxy_stream(res, seed),
        "hydrogen-shell" => hydrogen_shell_stream(res, seed),
        "three-cubes" => three_cubes_stream(res),
        "turbulence" => turbulence_stream(res, seed),
        "marschner-lobb" => marschner_lobb_stream(res),
        "channels12" => channels12_stream(res, seed),
        other => Err(Error::parameter(format!(
            "unknown dataset '{other}' (known: {})",
            NAMES.join(", ")
        ))),
    }
}

fn check_res(res: usize) -> Result<()> {
    if !(2..=2048).contains(&res) {
        return Err(Error::parameter(format!(
            "resolution {res} must be 2..=2048"
        )));
    }
    Ok(())
}

/// Geometry spanning `[lo, hi]` along each axis with `dims` voxels.
fn box_geometry(dims: [usize; 3], lo: Vec3, hi: Vec3) -> Geometry {
    let n = Vec3::new(
        dims[0] as f32 - 1.0,
        dims[1] as f32 - 1.0,
        dims[2] as f32 - 1.0,
    )
    .max(Vec3::ONE);
    Geometry {
        dims,
        origin: lo,
        spacing: (hi - lo) / n,
    }
}

fn hash(seed: u64, x: i64, y: i64, z: i64) -> f32 {
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for v in [x, y, z] {
        h = h.wrapping_add(v as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 31;
        h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
        h ^= h >> 29;
    }
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Value noise in [0, 1): hashed lattice values blended with smoothstep weights.
fn value_noise(p: Vec3, seed: u64) -> f32 {
    let f = p.floor();
    let t = p - f;
    let s = t * t * (Vec3::splat(3.0) - 2.0 * t);
    let (x, y, z) = (f.x as i64, f.y as i64, f.z as i64);
    let l = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let h = |dx, dy, dz| hash(seed, x + dx, y + dy, z + dz);
    let x00 = l(h(0, 0, 0), h(1, 0, 0), s.x);
    let x10 = l(h(0, 1, 0), h(1, 1, 0), s.x);
    let x01 = l(h(0, 0, 1), h(1, 0, 1), s.x);
    let x11 = l(h(0, 1, 1), h(1, 1, 1), s.x);
    l(l(x00, x10, s.y), l(x01, x11, s.y), s.z)
}

/// Fractal (fBm) noise in [-1, 1): `octaves` octaves, each twice the frequency and half the
/// amplitude.
fn fbm(p: Vec3, octaves: u32, seed: u64) -> f32 {
    let (mut sum, mut amp, mut norm, mut freq) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * (2.0 * value_noise(p * freq, seed.wrapping_add(u64::from(o) * 7919)) - 1.0);
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}

/// A rotating barred-disk galaxy standing in for the Doppler paper's Galaxy data (section 6).
///
/// Geometry: `res x res x res/2` voxels spanning x, y in [-15, 15] kpc and z in [-7.5, 7.5]
/// kpc (spacing in **kpc**), the disk in the xy plane, rotating counter-clockwise seen from
/// +z; all gas fades to zero over the outer 20 % of each half-side (no emission reaches the
/// box's faces). Channels:
/// - `hi_density`, `he_density`, `c_density`, `dust_density`: number densities in cm^-3
///   (H I exponential disk, scale length 4 kpc, scale height 0.4 kpc, a bar of half-length
///   4 kpc at 25 degrees, two log-spiral arms and seeded clumps; He ≈ 0.08 H I plus a
///   diffuse halo; C and dust trace the arms and bar);
/// - `temperature_k`: kelvin, from ~100 K in dense clumps through ~8000 K in the warm disk
///   to ~10^6 K in the halo;
/// - `velocity_m_per_s`: a flat rotation curve of 220 km/s (rising inside 1 kpc) plus bar
///   streaming of up to 60 km/s and 10 km/s seeded turbulence.
pub fn galaxy(res: usize, seed: u64) -> Result<Volume> {
    galaxy_stream(res, seed)?.to_volume()
}

/// [`galaxy`] as a [`Stream`].
pub fn galaxy_stream(res: usize, seed: u64) -> Result<Stream> {
    check_res(res)?;
    let dims = [res, res, (res / 2).max(2)];
    let geom = box_geometry(
        dims,
        Vec3::new(-15.0, -15.0, -7.5),
        Vec3::new(15.0, 15.0, 7.5),
    );
    let bar_angle = 25f32.to_radians();
    let (rd, hz) = (4.0f32, 0.4f32);
    // Shared structure factors.
    let structure = move |p: Vec3| -> (f32, f32, f32) {
        let r = p.x.hypot(p.y);
        let phi = p.y.atan2(p.x);
        // Bar: elongated Gaussian in the rotated frame.
        let (s, c) = bar_angle.sin_cos();
        let xb = c * p.x + s * p.y;
        let yb = -s * p.x + c * p.y;
        let bar = (-(xb / 4.0).powi(2) - (yb / 1.2).powi(2)).exp();
        // Two logarithmic spiral arms (pitch ~ 15 degrees), starting at the bar ends.
        let arm_phase =
            2.0 * (phi - bar_angle) - 2.0 / 15f32.to_radians().tan() * (r.max(0.5) / 4.0).ln();
        let arms = (0.5 + 0.5 * arm_phase.cos()).powi(4) * (1.0 - (-(r / 4.0).powi(2)).exp());
        let clump = (1.2 * fbm(p * 0.8, 4, seed)).exp();
        (r, 1.0 + 2.0 * bar + 2.5 * arms, clump)
    };
    // The gas fades to zero over the outer 20 % of each half-side (smoothstep), so no
    // emission is cut off by the box: a render shows the galaxy, not a glowing slab.
    let window = |p: Vec3| -> f32 {
        let s = |u: f32, half: f32| {
            let e = ((1.0 - u.abs() / half) / 0.2).clamp(0.0, 1.0);
            e * e * (3.0 - 2.0 * e)
        };
        s(p.x, 15.0) * s(p.y, 15.0) * s(p.z, 7.5)
    };
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        let (r, s, clump) = structure(p);
        let vertical = 1.0 / (p.z / hz).cosh().powi(2);
        let hi = 1.0 * (-r / rd).exp() * vertical * s * clump * window(p);
        let halo = 0.002 * (-(p.length() / 10.0)).exp() * window(p);
        let he = 0.08 * hi + halo;
        let c = 3e-4 * hi * (s - 1.0).max(0.0);
        let dust = 0.3 * c + 1e-3 * hi;
        let disk = 8000.0 / (1.0 + 20.0 * hi) + 100.0;
        let halo_w = 1.0 - (-(p.z / 1.5).powi(2)).exp();
        let temp = disk * (1.0 - halo_w) + 1.0e6 * halo_w;
        let r = p.x.hypot(p.y).max(1e-3);
        let vc = 220e3 * (1.0 - (-r / 1.0).exp());
        let tangential = Vec3::new(-p.y / r, p.x / r, 0.0);
        let radial = Vec3::new(p.x / r, p.y / r, 0.0);
        let phi = p.y.atan2(p.x);
        let v_bar = 60e3
            * (2.0 * (phi - bar_angle)).sin()
            * (r / 4.0)
            * (-r / 4.0).exp()
            * std::f32::consts::E;
        let turb = Vec3::new(
            fbm(p * 0.5, 3, seed ^ 1),
            fbm(p * 0.5, 3, seed ^ 2),
            fbm(p * 0.5, 3, seed ^ 3),
        ) * 10e3;
        let v = tangential * vc + radial * v_bar + turb;
        out.copy_from_slice(&[hi, he, c, dust, temp, v.x, v.y, v.z]);
    };
    Stream::new(
        geom,
        &[
            ("hi_density", 1),
            ("he_density", 1),
            ("c_density", 1),
            ("dust_density", 1),
            ("temperature_k", 1),
            ("velocity_m_per_s", 3),
        ],
        voxel,
    )
}

/// Shell radius of [`hydrogen_shell`] in world units (the cube spans [-1, 1]).
pub const SHELL_RADIUS: f32 = 0.6;
/// Shell thickness of [`hydrogen_shell`]: a tenth of the cube's side of 2.
pub const SHELL_THICKNESS: f32 = 0.2;
/// Equatorial speed of [`hydrogen_shell`] at [`SHELL_RADIUS`], m/s.
pub const SHELL_SPEED_M_PER_S: f32 = 300e3;

/// The synthetic hydrogen of Doppler Fig. 12: a shell of H I (radius 0.6, thickness 0.2, a
/// tenth of the side of the `[-1, 1]^3` cube) rotating rigidly about +y.
///
/// Velocity `v = ω × r` with `ω = (0, ω, 0)`, i.e. `v = (ω z, 0, -ω x)`, reaching 300 km/s
/// at the shell's equator. Seen along z (a camera at +z looking towards -z), the x > 0 side
/// moves away from the viewer (receding, red-shifted) and the x < 0 side approaches
/// (blue-shifted). `hi_density` is 1 cm^-3 in the shell with smooth edges and ±10 % seeded
/// clumpiness. Geometry in arbitrary world units.
pub fn hydrogen_shell(res: usize, seed: u64) -> Result<Volume> {
    hydrogen_shell_stream(res, seed)?.to_volume()
}

/// [`hydrogen_shell`] as a [`Stream`].
pub fn hydrogen_shell_stream(res: usize, seed: u64) -> Result<Stream> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::splat(-1.0), Vec3::splat(1.0));
    let half = SHELL_THICKNESS / 2.0;
    let omega = SHELL_SPEED_M_PER_S / SHELL_RADIUS;
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        let d = (p.length() - SHELL_RADIUS).abs();
        // Flat inside, smooth fall-off over the outer 30 % of the half-thickness.
        let edge = ((half - d) / (0.3 * half)).clamp(0.0, 1.0);
        let w = edge * edge * (3.0 - 2.0 * edge);
        let hi = w * (1.0 + 0.1 * fbm(p * 6.0, 3, seed));
        out.copy_from_slice(&[hi, omega * p.z, 0.0, -omega * p.x]);
    };
    Stream::new(geom, &[("hi_density", 1), ("velocity_m_per_s", 3)], voxel)
}

/// The boxes of [`three_cubes`] in the unit cube: `(min, max)` corners for red, green, blue.
pub const CUBES: [(Vec3, Vec3); 3] = [
    (Vec3::new(0.1, 0.1, 0.25), Vec3::new(0.6, 0.6, 0.75)),
    (Vec3::new(0.4, 0.1, 0.25), Vec3::new(0.9, 0.6, 0.75)),
    (Vec3::new(0.25, 0.4, 0.25), Vec3::new(0.75, 0.9, 0.75)),
];

/// The three overlapping cubes of MDWT Fig. 3 in the unit cube `[0, 1]^3`: channels `red`,
/// `green`, `blue`, each zero outside its box ([`CUBES`]) and, inside, a linear ramp from
/// 1 to 0 decreasing along +X (red), -X (green) and -Y (blue).
pub fn three_cubes(res: usize) -> Result<Volume> {
    three_cubes_stream(res)?.to_volume()
}

/// [`three_cubes`] as a [`Stream`].
pub fn three_cubes_stream(res: usize) -> Result<Stream> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        for (i, o) in out.iter_mut().enumerate() {
            let (lo, hi) = CUBES[i];
            *o = if p.cmplt(lo).any() || p.cmpgt(hi).any() {
                0.0
            } else {
                let u = (p - lo) / (hi - lo);
                match i {
                    0 => 1.0 - u.x,
                    1 => u.x,
                    _ => u.y,
                }
            };
        }
    };
    Stream::new(geom, &[("red", 1), ("green", 1), ("blue", 1)], voxel)
}

/// Decades spanned by [`turbulence`]: its values run from 10^-6.5 to 10^0.5.
pub const TURBULENCE_DECADES: f32 = 7.0;

/// A heavy-tailed turbulence-like density (HDR VolVis section 3): `10^(7 g - 6.5)` with `g`
/// six-octave fractal noise rescaled to [0, 1] over the grid, so values span exactly seven
/// decades, log-normally distributed with a long bright tail. Unit cube geometry.
pub fn turbulence(res: usize, seed: u64) -> Result<Volume> {
    turbulence_stream(res, seed)?.to_volume()
}

/// [`turbulence`] as a [`Stream`]. The rescaling needs the noise's range over the grid: a
/// first pass computes it without storing anything.
pub fn turbulence_stream(res: usize, seed: u64) -> Result<Stream> {
    use rayon::prelude::*;
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let freq = 4.0;
    let raw = move |x: usize, y: usize, z: usize| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        // Squaring sharpens the filaments: most of the volume is thin, a little is dense.
        let g = fbm(p * freq, 6, seed);
        g + 0.5 * g * g * g.signum()
    };
    let (lo, hi) = (0..res)
        .into_par_iter()
        .map(|z| {
            let mut r = (f32::INFINITY, f32::NEG_INFINITY);
            for y in 0..res {
                for x in 0..res {
                    let v = raw(x, y, z);
                    r = (r.0.min(v), r.1.max(v));
                }
            }
            r
        })
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
    let span = (hi - lo).max(f32::MIN_POSITIVE);
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        let u = (raw(x, y, z) - lo) / span;
        out[0] = 10f32.powf(TURBULENCE_DECADES * u - 6.5);
    };
    Stream::new(geom, &[("density", 1)], voxel)
}

/// The Marschner-Lobb test signal (Marschner & Lobb 1994) on `[-1, 1]^3` with the usual
/// `f_M = 6`, `α = 0.25`:
/// `ρ = (1 - sin(π z / 2) + α (1 + cos(2π f_M cos(π r / 2)))) / (2 (1 + α))`, `r = sqrt(x² + y²)`.
pub fn marschner_lobb(res: usize) -> Result<Volume> {
    marschner_lobb_stream(res)?.to_volume()
}

/// [`marschner_lobb`] as a [`Stream`].
pub fn marschner_lobb_stream(res: usize) -> Result<Stream> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::splat(-1.0), Vec3::splat(1.0));
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        out[0] = marschner_lobb_at(geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32)));
    };
    Stream::new(geom, &[("density", 1)], voxel)
}

/// The Marschner-Lobb function at a point (see [`marschner_lobb`]).
#[must_use]
pub fn marschner_lobb_at(p: Vec3) -> f32 {
    use std::f32::consts::PI;
    let (fm, alpha) = (6.0f32, 0.25f32);
    let r = p.x.hypot(p.y);
    let rho_r = (2.0 * PI * fm * (PI * r / 2.0).cos()).cos();
    (1.0 - (PI * p.z / 2.0).sin() + alpha * (1.0 + rho_r)) / (2.0 * (1.0 + alpha))
}

/// Twelve channels `c00` ... `c11` for channel-count sweeps: channel `i` is a Gaussian blob
/// (σ = 0.12) at a seeded position in the unit cube, times `1 + 0.3 fbm`, peak about 1.
pub fn channels12(res: usize, seed: u64) -> Result<Volume> {
    channels12_stream(res, seed)?.to_volume()
}

/// [`channels12`] as a [`Stream`].
pub fn channels12_stream(res: usize, seed: u64) -> Result<Stream> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let blobs: Vec<(u64, Vec3)> = (0..12u64)
        .map(|i| {
            let s = seed.wrapping_mul(1000).wrapping_add(i);
            let c = Vec3::new(hash(s, 1, 0, 0), hash(s, 2, 0, 0), hash(s, 3, 0, 0)) * 0.6
                + Vec3::splat(0.2);
            (s, c)
        })
        .collect();
    let names: Vec<String> = (0..12).map(|i| format!("c{i:02}")).collect();
    let channels: Vec<(&str, usize)> = names.iter().map(|n| (n.as_str(), 1)).collect();
    let voxel = move |[x, y, z]: [usize; 3], out: &mut [f32]| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        for (o, &(s, c)) in out.iter_mut().zip(&blobs) {
            let d2 = (p - c).length_squared();
            *o = (-d2 / (2.0 * 0.12 * 0.12)).exp() * (1.0 + 0.3 * fbm(p * 5.0, 3, s));
        }
    };
    Stream::new(geom, &channels, voxel)
}
