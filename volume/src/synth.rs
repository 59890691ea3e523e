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
use crate::volume::Volume;
use crate::{Error, Result};

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
    match name {
        "galaxy" => galaxy(res, seed),
        "hydrogen-shell" => hydrogen_shell(res, seed),
        "three-cubes" => three_cubes(res),
        "turbulence" => turbulence(res, seed),
        "marschner-lobb" => marschner_lobb(res),
        "channels12" => channels12(res, seed),
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
    check_res(res)?;
    let dims = [res, res, (res / 2).max(2)];
    let geom = box_geometry(
        dims,
        Vec3::new(-15.0, -15.0, -7.5),
        Vec3::new(15.0, 15.0, 7.5),
    );
    let bar_angle = 25f32.to_radians();
    let (rd, hz) = (4.0f32, 0.4f32);
    let pos =
        |x: usize, y: usize, z: usize| geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
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
    let hi = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        let (r, s, clump) = structure(p);
        let vertical = 1.0 / (p.z / hz).cosh().powi(2);
        1.0 * (-r / rd).exp() * vertical * s * clump * window(p)
    })?;
    let he = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        let halo = 0.002 * (-(p.length() / 10.0)).exp() * window(p);
        0.08 * hi.data()[geom.index(x, y, z)] + halo
    })?;
    let c = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        let (_, s, _) = structure(p);
        3e-4 * hi.data()[geom.index(x, y, z)] * (s - 1.0).max(0.0)
    })?;
    let dust = Grid::from_fn(geom, |x, y, z| {
        0.3 * c.data()[geom.index(x, y, z)] + 1e-3 * hi.data()[geom.index(x, y, z)]
    })?;
    let temp = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        let n = hi.data()[geom.index(x, y, z)];
        let disk = 8000.0 / (1.0 + 20.0 * n) + 100.0;
        let halo_w = 1.0 - (-(p.z / 1.5).powi(2)).exp();
        disk * (1.0 - halo_w) + 1.0e6 * halo_w
    })?;
    let vel = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
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
        tangential * vc + radial * v_bar + turb
    })?;
    let mut v = Volume::new(geom)?;
    v.push("hi_density", hi)?;
    v.push("he_density", he)?;
    v.push("c_density", c)?;
    v.push("dust_density", dust)?;
    v.push("temperature_k", temp)?;
    v.push("velocity_m_per_s", vel)?;
    Ok(v)
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
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::splat(-1.0), Vec3::splat(1.0));
    let pos =
        |x: usize, y: usize, z: usize| geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
    let half = SHELL_THICKNESS / 2.0;
    let hi = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        let d = (p.length() - SHELL_RADIUS).abs();
        // Flat inside, smooth fall-off over the outer 30 % of the half-thickness.
        let edge = ((half - d) / (0.3 * half)).clamp(0.0, 1.0);
        let w = edge * edge * (3.0 - 2.0 * edge);
        w * (1.0 + 0.1 * fbm(p * 6.0, 3, seed))
    })?;
    let omega = SHELL_SPEED_M_PER_S / SHELL_RADIUS;
    let vel = Grid::from_fn(geom, |x, y, z| {
        let p = pos(x, y, z);
        Vec3::new(omega * p.z, 0.0, -omega * p.x)
    })?;
    let mut v = Volume::new(geom)?;
    v.push("hi_density", hi)?;
    v.push("velocity_m_per_s", vel)?;
    Ok(v)
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
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let mut v = Volume::new(geom)?;
    for (i, name) in ["red", "green", "blue"].into_iter().enumerate() {
        let (lo, hi) = CUBES[i];
        let g = Grid::from_fn(geom, |x, y, z| {
            let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
            if p.cmplt(lo).any() || p.cmpgt(hi).any() {
                return 0.0;
            }
            let u = (p - lo) / (hi - lo);
            match i {
                0 => 1.0 - u.x,
                1 => u.x,
                _ => u.y,
            }
        })?;
        v.push(name, g)?;
    }
    Ok(v)
}

/// Decades spanned by [`turbulence`]: its values run from 10^-6.5 to 10^0.5.
pub const TURBULENCE_DECADES: f32 = 7.0;

/// A heavy-tailed turbulence-like density (HDR VolVis section 3): `10^(7 g - 6.5)` with `g`
/// six-octave fractal noise rescaled to [0, 1] over the grid, so values span exactly seven
/// decades, log-normally distributed with a long bright tail. Unit cube geometry.
pub fn turbulence(res: usize, seed: u64) -> Result<Volume> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let freq = 4.0;
    let raw = Grid::from_fn(geom, |x, y, z| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        // Squaring sharpens the filaments: most of the volume is thin, a little is dense.
        let g = fbm(p * freq, 6, seed);
        g + 0.5 * g * g * g.signum()
    })?;
    let (lo, hi) = raw
        .data()
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = (hi - lo).max(f32::MIN_POSITIVE);
    let g = Grid::from_fn(geom, |x, y, z| {
        let u = (raw.data()[geom.index(x, y, z)] - lo) / span;
        10f32.powf(TURBULENCE_DECADES * u - 6.5)
    })?;
    Volume::single("density", g)
}

/// The Marschner-Lobb test signal (Marschner & Lobb 1994) on `[-1, 1]^3` with the usual
/// `f_M = 6`, `α = 0.25`:
/// `ρ = (1 - sin(π z / 2) + α (1 + cos(2π f_M cos(π r / 2)))) / (2 (1 + α))`, `r = sqrt(x² + y²)`.
pub fn marschner_lobb(res: usize) -> Result<Volume> {
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::splat(-1.0), Vec3::splat(1.0));
    let g = Grid::from_fn(geom, |x, y, z| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        marschner_lobb_at(p)
    })?;
    Volume::single("density", g)
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
    check_res(res)?;
    let geom = box_geometry([res; 3], Vec3::ZERO, Vec3::ONE);
    let mut v = Volume::new(geom)?;
    for i in 0..12u64 {
        let s = seed.wrapping_mul(1000).wrapping_add(i);
        let c = Vec3::new(hash(s, 1, 0, 0), hash(s, 2, 0, 0), hash(s, 3, 0, 0)) * 0.6
            + Vec3::splat(0.2);
        let g = Grid::from_fn(geom, |x, y, z| {
            let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
            let d2 = (p - c).length_squared();
            (-d2 / (2.0 * 0.12 * 0.12)).exp() * (1.0 + 0.3 * fbm(p * 5.0, 3, s))
        })?;
        v.push(format!("c{i:02}"), g)?;
    }
    Ok(v)
}
