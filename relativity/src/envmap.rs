//! Environment maps: equirectangular and cube maps, the procedural checker, loading,
//! seamless bilinear sampling and layout conversion.
//!
//! ## Conventions
//! World axes are right-handed with `+Y` up.
//!
//! **Equirectangular**: column `u in [0, 1)` is the longitude `phi = atan2(x, -z)`,
//! `u = 0.5 + phi / (2 pi)` (so `-Z` is the image centre, `+X` at `u = 0.75`); row `v in [0, 1]`
//! is the polar angle from `+Y`, `v = acos(y) / pi` (top row looks up). Sampling wraps in `u`
//! and clamps in `v`.
//!
//! **Cube map**: the OpenGL/Vulkan convention (OpenGL 4.6 spec, table 8.19). Faces in order
//! `+X, -X, +Y, -Y, +Z, -Z` (files `px, nx, py, ny, pz, nz`). For the major axis `ma` the
//! face coordinates are (`sc`, `tc`): `+X: (-z, -y)`, `-X: (+z, -y)`, `+Y: (+x, +z)`,
//! `-Y: (+x, -z)`, `+Z: (+x, -y)`, `-Z: (-x, -y)`; `s = (sc / |ma| + 1) / 2` runs along
//! image columns and `t = (tc / |ma| + 1) / 2` along rows from the top row of the file.
//!
//! **Single-file layouts** ([`MapLayout`], chosen by the aspect ratio; any other ratio is
//! refused, never read as a distorted equirectangular map):
//! - 2:1: equirectangular (above).
//! - 1:6 vertical strip: OpenEXR's `envmap = CUBE` layout (`ImfEnvmap.h`), faces `+X, -X,
//!   +Y, -Y, +Z, -Z` from top to bottom in OpenEXR's own per-face orientation and frame.
//!   OpenEXR's lat-long frame is this module's turned 180 degrees about `+Y` (its image
//!   centre looks along `+Z`, ours along `-Z`), so a direction `(x, y, z)` here is looked
//!   up at `(-x, y, -z)` in the OpenEXR cube: an OpenEXR lat-long map and its cube map
//!   then show the same sky (`KernerEnvLatLong.exr` / `KernerEnvCube.exr`).
//! - 6:1 horizontal strip: faces `+X, -X, +Y, -Y, +Z, -Z` from left to right, each in this
//!   module's OpenGL orientation (the six files of a folder side by side).
//! - 4:3 horizontal cross: `+Y` above `+Z`, the middle row `-X, +Z, +X, -Z`, `-Y` below
//!   `+Z`, all in the OpenGL orientation (the unfolded cube is continuous across edges).
//! - 3:4 vertical cross: `+Y`, then `-X, +Z, +X`, then `-Y`, then `-Z` turned 180 degrees,
//!   in the second column (continuous across edges too).

use std::path::{Path, PathBuf};

use glam::DVec3;
use image::{ImageReader, Limits, Rgb32FImage};

use crate::error::{Error, Result};

/// The largest accepted map side, in pixels (larger files are refused before decoding).
pub const MAX_MAP_SIDE: u32 = 32_768;
/// The largest accepted decoded map, in bytes.
pub const MAX_MAP_BYTES: u64 = 4 << 30;

/// Linear RGB, `f32` per channel.
pub type Rgb = [f32; 3];

/// An equirectangular (latitude-longitude) map; see the module docs for the convention.
#[derive(Clone, Debug)]
pub struct EquirectMap {
    image: Rgb32FImage,
}

/// A cube map of six square faces of equal size, in the order `+X, -X, +Y, -Y, +Z, -Z`.
#[derive(Clone, Debug)]
pub struct CubeMap {
    faces: [Rgb32FImage; 6],
    size: u32,
}

/// A procedural checkerboard on the sphere: cells of `cell_deg` in longitude and latitude
/// (same angles as the equirectangular layout), alternately `light` and `dark`, with thin
/// grid lines `line` of width `line_deg` on every `grid_deg` meridian and parallel.
#[derive(Clone, Debug, PartialEq)]
pub struct Checker {
    /// Cell size in degrees.
    pub cell_deg: f64,
    /// Light cell colour.
    pub light: Rgb,
    /// Dark cell colour.
    pub dark: Rgb,
    /// Grid line spacing in degrees (0: no lines).
    pub grid_deg: f64,
    /// Grid line width in degrees.
    pub line_deg: f64,
    /// Grid line colour.
    pub line: Rgb,
}

impl Default for Checker {
    fn default() -> Self {
        Self {
            cell_deg: 10.0,
            light: [0.8, 0.8, 0.8],
            dark: [0.1, 0.1, 0.1],
            grid_deg: 30.0,
            line_deg: 0.4,
            line: [1.0, 0.35, 0.05],
        }
    }
}

/// Longitude `atan2(x, -z)` in `(-pi, pi]` and polar angle from `+Y` in `[0, pi]` of a unit
/// direction.
#[must_use]
pub fn lon_polar(d: DVec3) -> (f64, f64) {
    (d.x.atan2(-d.z), d.y.clamp(-1.0, 1.0).acos())
}

/// The unit direction of longitude `lon` and polar angle `polar` (inverse of [`lon_polar`]).
#[must_use]
pub fn from_lon_polar(lon: f64, polar: f64) -> DVec3 {
    let s = polar.sin();
    DVec3::new(s * lon.sin(), polar.cos(), -s * lon.cos())
}

impl Checker {
    /// The colour in unit direction `d` (nearest, no filtering).
    #[must_use]
    pub fn sample(&self, d: DVec3) -> Rgb {
        let (lon, polar) = lon_polar(d);
        let lon_deg = lon.to_degrees() + 180.0;
        let lat_deg = polar.to_degrees();
        if self.grid_deg > 0.0 {
            let near = |a: f64| {
                let r = a.rem_euclid(self.grid_deg);
                r.min(self.grid_deg - r) < 0.5 * self.line_deg
            };
            if near(lon_deg) || near(lat_deg) {
                return self.line;
            }
        }
        let i = (lon_deg / self.cell_deg).floor() as i64;
        let j = (lat_deg / self.cell_deg).floor() as i64;
        if (i + j).rem_euclid(2) == 0 {
            self.light
        } else {
            self.dark
        }
    }
}

#[inline]
fn texel(img: &Rgb32FImage, x: u32, y: u32) -> Rgb {
    img.get_pixel(x, y).0
}

#[inline]
fn lerp3(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn check_image(path: &Path, img: &Rgb32FImage) -> Result<()> {
    let (w, h) = img.dimensions();
    if w == 0 || h == 0 {
        return Err(Error::map(path, "the image is empty"));
    }
    if img.pixels().any(|p| p.0.iter().any(|c| !c.is_finite())) {
        return Err(Error::map(path, "the image has NaN or infinite texels"));
    }
    Ok(())
}

impl EquirectMap {
    /// A map from a linear RGB image (any size >= 1x1; 2:1 is usual). Refuses NaN/Inf texels.
    pub fn new(image: Rgb32FImage) -> Result<Self> {
        check_image(Path::new("<memory>"), &image)?;
        Ok(Self { image })
    }

    /// The image.
    #[must_use]
    pub fn image(&self) -> &Rgb32FImage {
        &self.image
    }

    /// Bilinear sample in unit direction `d` (wraps in longitude, clamps at the poles).
    #[must_use]
    pub fn sample(&self, d: DVec3) -> Rgb {
        let (w, h) = self.image.dimensions();
        let (lon, polar) = lon_polar(d);
        let u = 0.5 + lon / std::f64::consts::TAU;
        let v = polar / std::f64::consts::PI;
        let x = u * f64::from(w) - 0.5;
        let y = (v * f64::from(h) - 0.5).clamp(0.0, f64::from(h - 1));
        let x0 = x.floor();
        let y0 = y.floor();
        let fx = (x - x0) as f32;
        let fy = (y - y0) as f32;
        let wi = i64::from(w);
        let xa = (x0 as i64).rem_euclid(wi) as u32;
        let xb = (x0 as i64 + 1).rem_euclid(wi) as u32;
        let ya = y0 as u32;
        let yb = (ya + 1).min(h - 1);
        let top = lerp3(texel(&self.image, xa, ya), texel(&self.image, xb, ya), fx);
        let bot = lerp3(texel(&self.image, xa, yb), texel(&self.image, xb, yb), fx);
        lerp3(top, bot, fy)
    }
}

/// Face file names in cube-map order.
pub const FACE_NAMES: [&str; 6] = ["px", "nx", "py", "ny", "pz", "nz"];

/// The face index and face coordinates `(s, t)` in `[0, 1]` of a direction (OpenGL rule).
#[must_use]
pub fn cube_face_st(d: DVec3) -> (usize, f64, f64) {
    let a = d.abs();
    let (face, sc, tc, ma) = if a.x >= a.y && a.x >= a.z {
        if d.x > 0.0 {
            (0, -d.z, -d.y, a.x)
        } else {
            (1, d.z, -d.y, a.x)
        }
    } else if a.y >= a.z {
        if d.y > 0.0 {
            (2, d.x, d.z, a.y)
        } else {
            (3, d.x, -d.z, a.y)
        }
    } else if d.z > 0.0 {
        (4, d.x, -d.y, a.z)
    } else {
        (5, -d.x, -d.y, a.z)
    };
    (face, 0.5 * (sc / ma + 1.0), 0.5 * (tc / ma + 1.0))
}

/// The (unnormalised) direction of face coordinates `(s, t)` on `face` (inverse of
/// [`cube_face_st`]; `s`, `t` may lie outside `[0, 1]`, extending the face's plane).
#[must_use]
pub fn cube_dir(face: usize, s: f64, t: f64) -> DVec3 {
    let sc = 2.0 * s - 1.0;
    let tc = 2.0 * t - 1.0;
    match face {
        0 => DVec3::new(1.0, -tc, -sc),
        1 => DVec3::new(-1.0, -tc, sc),
        2 => DVec3::new(sc, 1.0, tc),
        3 => DVec3::new(sc, -1.0, -tc),
        4 => DVec3::new(sc, -tc, 1.0),
        _ => DVec3::new(-sc, -tc, -1.0),
    }
}

impl CubeMap {
    /// A cube map from six square faces of equal size, order `+X, -X, +Y, -Y, +Z, -Z`.
    pub fn new(faces: [Rgb32FImage; 6]) -> Result<Self> {
        let size = faces[0].width();
        for (f, name) in faces.iter().zip(FACE_NAMES) {
            check_image(Path::new(name), f)?;
            if f.width() != size || f.height() != size {
                return Err(Error::map(
                    name,
                    format!(
                        "cube faces must be square and equal: {}x{} vs {size}x{size}",
                        f.width(),
                        f.height()
                    ),
                ));
            }
        }
        Ok(Self { faces, size })
    }

    /// The face side in pixels.
    #[must_use]
    pub fn size(&self) -> u32 {
        self.size
    }

    /// The faces, order `+X, -X, +Y, -Y, +Z, -Z`.
    #[must_use]
    pub fn faces(&self) -> &[Rgb32FImage; 6] {
        &self.faces
    }

    /// The texel `(i, j)` of `face` where `i`, `j` may be one step outside the face: such
    /// taps are taken from the neighbouring face through the direction of the texel centre,
    /// which makes bilinear filtering continuous across face edges.
    #[inline]
    fn tap(&self, face: usize, i: i64, j: i64) -> Rgb {
        let n = i64::from(self.size);
        if (0..n).contains(&i) && (0..n).contains(&j) {
            return texel(&self.faces[face], i as u32, j as u32);
        }
        let nf = n as f64;
        let d = cube_dir(face, (i as f64 + 0.5) / nf, (j as f64 + 0.5) / nf);
        let (f2, s, t) = cube_face_st(d);
        let x = ((s * nf) as i64).clamp(0, n - 1) as u32;
        let y = ((t * nf) as i64).clamp(0, n - 1) as u32;
        texel(&self.faces[f2], x, y)
    }

    /// Seamless bilinear sample in direction `d` (need not be normalised, must not be zero).
    #[must_use]
    pub fn sample(&self, d: DVec3) -> Rgb {
        let (face, s, t) = cube_face_st(d);
        let n = f64::from(self.size);
        let x = s * n - 0.5;
        let y = t * n - 0.5;
        let x0 = x.floor();
        let y0 = y.floor();
        let fx = (x - x0) as f32;
        let fy = (y - y0) as f32;
        let (i, j) = (x0 as i64, y0 as i64);
        let top = lerp3(self.tap(face, i, j), self.tap(face, i + 1, j), fx);
        let bot = lerp3(self.tap(face, i, j + 1), self.tap(face, i + 1, j + 1), fx);
        lerp3(top, bot, fy)
    }
}

/// An environment the renderer can sample.
#[derive(Clone, Debug)]
pub enum Environment {
    /// Equirectangular map.
    Equirect(EquirectMap),
    /// Cube map.
    Cube(CubeMap),
    /// Procedural checkerboard with grid lines.
    Checker(Checker),
}

/// The extensions of the image files an environment is read from (single maps and faces).
const IMAGE_EXTENSIONS: [&str; 5] = ["exr", "hdr", "pic", "png", "pfm"];

impl Environment {
    /// Linear RGB radiance in unit direction `d` (scene frame).
    #[must_use]
    pub fn sample(&self, d: DVec3) -> Rgb {
        match self {
            Self::Equirect(m) => m.sample(d),
            Self::Cube(m) => m.sample(d),
            Self::Checker(c) => c.sample(d),
        }
    }

    /// Loads an environment: a folder holding `px, nx, py, ny, pz, nz` with any supported
    /// extension is a cube map; so is a path prefix `P` with files `Ppx.*` ... `Pnz.*`; a
    /// single `.exr`, `.hdr`, `.pfm` or `.png` file is read by its aspect ratio ([`MapLayout`]):
    /// 2:1 equirectangular, a cube strip or cross as a cube map, anything else refused.
    pub fn load(path: &Path) -> Result<Self> {
        let image_ext = path
            .extension()
            .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)));
        if image_ext && !path.exists() {
            return Err(Error::map(path, "no such file"));
        }
        if path.is_file() {
            let img = read_linear(path)?;
            check_image(path, &img)?;
            return Self::from_single_image(img).map_err(|e| match e {
                Error::MalformedMap { reason, .. } => Error::map(path, reason),
                other => other,
            });
        }
        let (dir, prefix) = if path.is_dir() {
            (path.to_path_buf(), String::new())
        } else {
            let dir = match path.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            let prefix = path
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            (dir, prefix)
        };
        let entries = std::fs::read_dir(&dir)
            .map_err(|e| Error::map(path, format!("not a file or cube-map folder/prefix: {e}")))?;
        let mut found: [Option<PathBuf>; 6] = Default::default();
        for entry in entries.flatten() {
            let p = entry.path();
            let (Some(stem), Some(ext)) = (p.file_stem(), p.extension()) else {
                continue;
            };
            let ext = ext.to_string_lossy().to_ascii_lowercase();
            if !IMAGE_EXTENSIONS.contains(&ext.as_str()) {
                continue;
            }
            let stem = stem.to_string_lossy();
            let face = stem
                .strip_prefix(prefix.as_str())
                .and_then(|rest| FACE_NAMES.iter().position(|n| *n == rest));
            if let Some(k) = face {
                if found[k].is_some() {
                    return Err(Error::map(
                        path,
                        format!("face {} is given by more than one file", FACE_NAMES[k]),
                    ));
                }
                found[k] = Some(p);
            }
        }
        let missing: Vec<&str> = FACE_NAMES
            .iter()
            .zip(&found)
            .filter(|(_, f)| f.is_none())
            .map(|(n, _)| *n)
            .collect();
        if !missing.is_empty() {
            return Err(Error::map(
                path,
                format!("cube map faces missing: {}", missing.join(", ")),
            ));
        }
        let mut faces = Vec::with_capacity(6);
        for f in found.into_iter().flatten() {
            faces.push(read_linear(&f)?);
        }
        let faces: [Rgb32FImage; 6] = faces
            .try_into()
            .map_err(|_| Error::map(path, "six faces expected"))?;
        CubeMap::new(faces).map(Self::Cube).map_err(|e| match e {
            Error::MalformedMap { reason, .. } => Error::map(path, reason),
            other => other,
        })
    }

    /// Resamples into an equirectangular map of `width x height` (bilinear source sampling
    /// at texel centres).
    pub fn to_equirect(&self, width: u32, height: u32) -> Result<EquirectMap> {
        check_size(width, height)?;
        let mut img = Rgb32FImage::new(width, height);
        for (x, y, p) in img.enumerate_pixels_mut() {
            let lon = ((f64::from(x) + 0.5) / f64::from(width) - 0.5) * std::f64::consts::TAU;
            let polar = (f64::from(y) + 0.5) / f64::from(height) * std::f64::consts::PI;
            p.0 = self.sample(from_lon_polar(lon, polar));
        }
        EquirectMap::new(img)
    }

    /// Resamples into a cube map with faces of `size x size`.
    pub fn to_cube(&self, size: u32) -> Result<CubeMap> {
        check_size(size, size)?;
        let faces: [Rgb32FImage; 6] = std::array::from_fn(|f| {
            let mut img = Rgb32FImage::new(size, size);
            let n = f64::from(size);
            for (x, y, p) in img.enumerate_pixels_mut() {
                let d = cube_dir(f, (f64::from(x) + 0.5) / n, (f64::from(y) + 0.5) / n);
                p.0 = self.sample(d.normalize());
            }
            img
        });
        CubeMap::new(faces)
    }
}

/// The layout of a single-file environment map, told by its aspect ratio (see the module
/// docs for each layout's face order and orientation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapLayout {
    /// 2:1 latitude-longitude.
    Equirect,
    /// 1:6: OpenEXR's vertical cube strip (`envmap = CUBE`).
    StripVertical,
    /// 6:1: the six OpenGL-oriented faces side by side.
    StripHorizontal,
    /// 4:3: the unfolded cube, `-X, +Z, +X, -Z` across the middle row.
    CrossHorizontal,
    /// 3:4: the unfolded cube, `-Z` at the bottom turned 180 degrees.
    CrossVertical,
}

impl MapLayout {
    /// The layout of a `width x height` image, or `None` for any other aspect ratio.
    #[must_use]
    pub fn detect(width: u32, height: u32) -> Option<Self> {
        let (w, h) = (u64::from(width), u64::from(height));
        if w == 0 || h == 0 {
            None
        } else if w == 2 * h {
            Some(Self::Equirect)
        } else if h == 6 * w {
            Some(Self::StripVertical)
        } else if w == 6 * h {
            Some(Self::StripHorizontal)
        } else if 3 * w == 4 * h && w % 4 == 0 {
            Some(Self::CrossHorizontal)
        } else if 4 * w == 3 * h && w % 3 == 0 {
            Some(Self::CrossVertical)
        } else {
            None
        }
    }

    /// The face side in pixels of a cube layout of an image `width` wide.
    fn face_size(self, width: u32) -> u32 {
        match self {
            Self::Equirect => 0,
            Self::StripVertical => width,
            Self::StripHorizontal => width / 6,
            Self::CrossHorizontal => width / 4,
            Self::CrossVertical => width / 3,
        }
    }

    /// The texel (column, row) of the whole image seen in unit direction `d` (this module's
    /// frame), for a cube layout with faces of `n` pixels.
    fn texel(self, d: DVec3, n: u32) -> (u32, u32) {
        let nf = f64::from(n);
        let cell = |s: f64| ((s * nf).floor().max(0.0) as u32).min(n - 1);
        if self == Self::StripVertical {
            // OpenEXR frame and per-face (u, v) in [-1, 1], u right, v down (ImfEnvmap).
            let e = DVec3::new(-d.x, d.y, -d.z);
            let a = e.abs();
            let (face, u, v) = if a.x >= a.y && a.x >= a.z {
                (if e.x > 0.0 { 0 } else { 1 }, e.z / e.x, -e.y / a.x)
            } else if a.y >= a.z {
                if e.y > 0.0 {
                    (2, e.x / a.y, -e.z / a.y)
                } else {
                    (3, e.x / a.y, e.z / a.y)
                }
            } else if e.z > 0.0 {
                (4, -e.x / a.z, -e.y / a.z)
            } else {
                (5, e.x / a.z, -e.y / a.z)
            };
            return (cell(0.5 * (u + 1.0)), face * n + cell(0.5 * (v + 1.0)));
        }
        let (face, s, t) = cube_face_st(d);
        let (i, j) = (cell(s), cell(t));
        // (column, row) of each face's cell and whether it is turned 180 degrees.
        let (cx, cy, turned) = match (self, face) {
            (Self::StripHorizontal, f) => (f as u32, 0, false),
            (_, 2) => (1, 0, false),
            (_, 3) => (1, 2, false),
            (_, 0) => (2, 1, false),
            (_, 1) => (0, 1, false),
            (_, 4) => (1, 1, false),
            (Self::CrossHorizontal, _) => (3, 1, false),
            (_, _) => (1, 3, true),
        };
        let (i, j) = if turned {
            (n - 1 - i, n - 1 - j)
        } else {
            (i, j)
        };
        (cx * n + i, cy * n + j)
    }
}

impl Environment {
    /// An environment from one linear RGB image, by its [`MapLayout`]; an aspect ratio that
    /// is none of the layouts is refused with [`Error::MalformedMap`].
    pub fn from_single_image(img: Rgb32FImage) -> Result<Self> {
        let (w, h) = img.dimensions();
        let layout = MapLayout::detect(w, h).ok_or_else(|| {
            Error::map(
                "<image>",
                format!(
                    "{w}x{h} is neither a 2:1 equirectangular map nor a cube map (a 1:6 or \
                     6:1 strip of six faces, a 4:3 or 3:4 cross); give six face files in a \
                     folder instead"
                ),
            )
        })?;
        if layout == MapLayout::Equirect {
            return EquirectMap::new(img).map(Self::Equirect);
        }
        let n = layout.face_size(w);
        let nf = f64::from(n);
        let faces: [Rgb32FImage; 6] = std::array::from_fn(|f| {
            let mut face = Rgb32FImage::new(n, n);
            for (i, j, p) in face.enumerate_pixels_mut() {
                let d = cube_dir(f, (f64::from(i) + 0.5) / nf, (f64::from(j) + 0.5) / nf);
                let (x, y) = layout.texel(d.normalize(), n);
                p.0 = texel(&img, x, y);
            }
            face
        });
        CubeMap::new(faces).map(Self::Cube)
    }
}

/// Refuses zero and absurd image sizes: each edge 1 to 32768 pixels, and at most
/// [`MAX_MAP_BYTES`] of linear RGB f32 in all (so no size asks for more than 4 GiB).
pub fn check_size(width: u32, height: u32) -> Result<()> {
    for (name, v) in [("width (pixels)", width), ("height (pixels)", height)] {
        if v == 0 || v > MAX_MAP_SIDE {
            return Err(Error::param(name, f64::from(v), "must be in 1..=32768"));
        }
    }
    let bytes = u64::from(width) * u64::from(height) * 12;
    if bytes > MAX_MAP_BYTES {
        return Err(Error::param(
            "image size (pixels)",
            f64::from(width) * f64::from(height),
            "needs more than 4 GiB of RGB f32: at most 357,913,941 pixels",
        ));
    }
    Ok(())
}

impl EquirectMap {
    /// Reads an equirectangular map from an EXR, `.hdr` or PNG file.
    pub fn new_at(path: &Path) -> Result<Self> {
        let img = read_linear(path)?;
        check_image(path, &img)?;
        Ok(Self { image: img })
    }
}

/// A Radiance `.hdr` file whose `#?RADIANCE` (or `#?RGBE`) signature follows other header
/// lines (`VIEW=` first, as in Debevec's `memorial.hdr`), from its signature on: the image
/// crate's decoder wants the signature first, Radiance's own tools do not. `None` for any
/// other file (read as it is).
fn radiance_after_preamble(path: &Path) -> std::io::Result<Option<Vec<u8>>> {
    use std::io::Read as _;
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr") || e.eq_ignore_ascii_case("pic"))
    {
        return Ok(None);
    }
    let mut f = std::fs::File::open(path)?;
    let mut head = Vec::new();
    (&mut f).take(4096).read_to_end(&mut head)?;
    if head.starts_with(b"#?") {
        return Ok(None);
    }
    let Some(at) = head.windows(3).position(|w| w == b"\n#?").map(|i| i + 1) else {
        return Ok(None);
    };
    let len = f.metadata()?.len();
    if len > MAX_MAP_BYTES {
        return Err(std::io::Error::other(format!(
            "{len} bytes, more than the {MAX_MAP_BYTES} an environment map may have"
        )));
    }
    let mut bytes = head.split_off(at);
    f.read_to_end(&mut bytes)?;
    Ok(Some(bytes))
}

/// Reads an image as linear RGB: float formats (EXR, `.hdr`, `.pfm`) as they are, 8/16-bit
/// formats (PNG) through the sRGB decoding curve. Dimensions and memory are limited before decoding.
pub fn read_linear(path: &Path) -> Result<Rgb32FImage> {
    let ierr = |source| Error::Image {
        path: path.to_path_buf(),
        source,
    };
    // OpenEXR and PFM through blueshift's HDR reader, as `tonemap` reads them: every
    // OpenEXR layout it reads (luminance/chroma, multi-part, PIZ...), and PFM, which the
    // image crate does not read.
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pfm") || e.eq_ignore_ascii_case("exr"))
    {
        let side = u64::from(MAX_MAP_SIDE);
        let limits = blueshift_tonemap::io::Limits {
            max_pixels: side * side,
            max_bytes: MAX_MAP_BYTES,
        };
        return Ok(blueshift_tonemap::io::read_hdr_image_with(path, &limits)?);
    }
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_MAP_SIDE);
    limits.max_image_height = Some(MAX_MAP_SIDE);
    limits.max_alloc = Some(MAX_MAP_BYTES);
    let img =
        match radiance_after_preamble(path).map_err(|e| ierr(image::ImageError::IoError(e)))? {
            Some(bytes) => {
                let mut reader =
                    ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Hdr);
                reader.limits(limits);
                reader.decode().map_err(ierr)?
            }
            None => {
                let mut reader = ImageReader::open(path)
                    .map_err(|e| ierr(image::ImageError::IoError(e)))?
                    .with_guessed_format()
                    .map_err(|e| ierr(image::ImageError::IoError(e)))?;
                reader.limits(limits);
                reader.decode().map_err(ierr)?
            }
        };
    let float = matches!(
        img,
        image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
    );
    let mut rgb = img.into_rgb32f();
    if !float {
        for p in rgb.pixels_mut() {
            for c in &mut p.0 {
                *c = blueshift_spectrum::srgb_decode(f64::from(*c)) as f32;
            }
        }
    }
    Ok(rgb)
}
