//! Cameras and rays.
//!
//! Conventions: right-handed world; a camera looks from `eye` towards `target` with `up`
//! roughly up; image x grows along `forward x up` (the camera's right), image y grows
//! downwards (row 0 is the top). Ray directions are unit vectors, so the ray parameter `t`
//! is a world length.

use glam::Vec3;

use crate::{Error, Result};

/// A ray `origin + t * dir`, `dir` of unit length (so `t` is in world units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point (world units).
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// A ray from `origin` along `dir` (normalised here); `None` if `dir` is zero or not
    /// finite, or `origin` is not finite.
    #[must_use]
    pub fn new(origin: Vec3, dir: Vec3) -> Option<Self> {
        let dir = dir.try_normalize()?;
        origin.is_finite().then_some(Ray { origin, dir })
    }

    /// The point at parameter `t`.
    #[inline]
    #[must_use]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// The parameter range `[t_near, t_far]` where the ray is inside the closed box
    /// `[lo, hi]`, intersected with `t >= 0` (slab method; rays parallel to a slab are inside
    /// it when their origin is, including on its faces). `None` if the ray misses.
    #[must_use]
    pub fn clip_box(&self, lo: Vec3, hi: Vec3) -> Option<(f32, f32)> {
        let mut t0 = 0.0f32;
        let mut t1 = f32::INFINITY;
        for a in 0..3 {
            let o = self.origin[a];
            let d = self.dir[a];
            if d == 0.0 {
                if o < lo[a] || o > hi[a] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d;
            let (mut ta, mut tb) = ((lo[a] - o) * inv, (hi[a] - o) * inv);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
        }
        (t0 <= t1 && t1.is_finite()).then_some((t0, t1))
    }
}

/// How a camera projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Pinhole camera with a vertical field of view in degrees (0 < fov < 180).
    Perspective {
        /// Vertical field of view, degrees.
        fov_y_deg: f32,
    },
    /// Parallel rays; the image spans `height` world units vertically.
    Orthographic {
        /// Height of the view in world units (width follows from the aspect ratio).
        height: f32,
    },
}

/// A look-at camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (world units); for orthographic cameras the plane rays start from.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Approximate up direction.
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
}

/// Default vertical field of view of [`Camera::default_view`], degrees.
pub const DEFAULT_FOV_Y_DEG: f32 = 30.0;

impl Camera {
    /// Checks that the camera can make rays: finite positions, eye != target, `up` not
    /// parallel to the view direction, a field of view in (0, 180) or a positive height.
    pub fn validate(&self) -> Result<()> {
        if !(self.eye.is_finite() && self.target.is_finite() && self.up.is_finite()) {
            return Err(Error::parameter(
                "camera: eye, target and up must be finite",
            ));
        }
        let f = (self.target - self.eye)
            .try_normalize()
            .ok_or_else(|| Error::parameter("camera: eye and target coincide"))?;
        if f.cross(self.up).length_squared() < 1e-12 {
            return Err(Error::parameter(
                "camera: up is parallel to the view direction",
            ));
        }
        match self.projection {
            Projection::Perspective { fov_y_deg } if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) => {
                Err(Error::parameter(format!(
                    "camera: field of view {fov_y_deg} must be in (0, 180) degrees"
                )))
            }
            Projection::Orthographic { height } if !(height > 0.0 && height.is_finite()) => {
                Err(Error::parameter(format!(
                    "camera: orthographic height {height} must be positive"
                )))
            }
            _ => Ok(()),
        }
    }

    /// The default view of a box `[lo, hi]`: looking along +z through the box centre with +y
    /// up. `orthographic` frames the box's x-y extent exactly for an image of aspect
    /// `width / height`; the perspective camera (30 degree vertical field of view) stands
    /// back far enough that the x-y extent of the near face fits.
    #[must_use]
    pub fn default_view(lo: Vec3, hi: Vec3, aspect: f32, orthographic: bool) -> Camera {
        let centre = 0.5 * (lo + hi);
        let ext = (hi - lo).max(Vec3::splat(1e-6));
        let aspect = if aspect > 0.0 && aspect.is_finite() {
            aspect
        } else {
            1.0
        };
        let frame_h = ext.y.max(ext.x / aspect);
        if orthographic {
            let eye = Vec3::new(centre.x, centre.y, lo.z - ext.z - 1.0);
            Camera {
                eye,
                target: Vec3::new(centre.x, centre.y, centre.z),
                up: Vec3::Y,
                projection: Projection::Orthographic { height: frame_h },
            }
        } else {
            let half = (DEFAULT_FOV_Y_DEG.to_radians() * 0.5).tan();
            let dist = 0.5 * frame_h / half + 0.5 * ext.z;
            Camera {
                eye: centre - Vec3::Z * dist,
                target: centre,
                up: Vec3::Y,
                projection: Projection::Perspective {
                    fov_y_deg: DEFAULT_FOV_Y_DEG,
                },
            }
        }
    }

    /// The camera's orthonormal frame `(forward, right, up)`: forward from eye to target,
    /// right = forward x up, up = right x forward (a degenerate camera gives +z, +x, +y).
    /// Every backend builds its rays from this frame.
    #[must_use]
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = (self.target - self.eye).try_normalize().unwrap_or(Vec3::Z);
        let r = f.cross(self.up).try_normalize().unwrap_or(Vec3::X);
        (f, r, r.cross(f))
    }

    /// The ray through continuous pixel position `(px, py)` of a `width x height` image
    /// (pixel `(i, j)` covers `[i, i+1) x [j, j+1)`; row 0 is the top). Call
    /// [`Camera::validate`] first; a degenerate camera gives a ray along +z.
    #[must_use]
    pub fn ray(&self, px: f32, py: f32, width: u32, height: u32) -> Ray {
        let (f, r, u) = self.basis();
        let aspect = width as f32 / height.max(1) as f32;
        // Screen coordinates in [-1, 1] vertically, [-aspect, aspect] horizontally.
        let sx = (2.0 * px / width.max(1) as f32 - 1.0) * aspect;
        let sy = 1.0 - 2.0 * py / height.max(1) as f32;
        match self.projection {
            Projection::Perspective { fov_y_deg } => {
                let h = (fov_y_deg.to_radians() * 0.5).tan();
                let d = f + r * (sx * h) + u * (sy * h);
                Ray {
                    origin: self.eye,
                    dir: d.normalize(),
                }
            }
            Projection::Orthographic { height } => {
                let half = 0.5 * height;
                Ray {
                    origin: self.eye + r * (sx * half) + u * (sy * half),
                    dir: f,
                }
            }
        }
    }
}
