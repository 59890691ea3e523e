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

/// `v` scaled to unit length; `None` if it is zero or not finite. Scaled by its largest
/// component first, so vectors whose squared length overflows f32 (world distances above
/// about 1.8e19, as in volumes measured in centimetres) or underflows it still normalise.
#[must_use]
pub fn unit(v: Vec3) -> Option<Vec3> {
    let m = v.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    (v / m).try_normalize()
}

impl Ray {
    /// A ray from `origin` along `dir` (normalised here); `None` if `dir` is zero or not
    /// finite, or `origin` is not finite.
    #[must_use]
    pub fn new(origin: Vec3, dir: Vec3) -> Option<Self> {
        let dir = unit(dir)?;
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
        let f = unit(self.target - self.eye)
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

    /// The default view of a box `[lo, hi]`, yt's convention: the observer on the +z side
    /// looking towards -z through the box centre, world +x to the image's right and +y up
    /// ([`View::Z`]). `orthographic` frames the box's x-y extent exactly for an image of
    /// aspect `width / height`; the perspective camera (30 degree vertical field of view)
    /// stands back far enough that the x-y extent of the near face fits.
    #[must_use]
    pub fn default_view(lo: Vec3, hi: Vec3, aspect: f32, orthographic: bool) -> Camera {
        Camera::framing(
            lo,
            hi,
            Vec3::Z,
            Vec3::Y,
            aspect,
            orthographic,
            DEFAULT_FOV_Y_DEG,
        )
        .unwrap_or(Camera {
            eye: 0.5 * (lo + hi) + Vec3::Z,
            target: 0.5 * (lo + hi),
            up: Vec3::Y,
            projection: Projection::Orthographic { height: 1.0 },
        })
    }

    /// The view of `view` framing the box `[lo, hi]` (see [`Camera::framing`]).
    #[must_use]
    pub fn view_of(lo: Vec3, hi: Vec3, view: View, aspect: f32, orthographic: bool) -> Camera {
        let n = view.normal();
        Camera::framing(
            lo,
            hi,
            n,
            up_for(n),
            aspect,
            orthographic,
            DEFAULT_FOV_Y_DEG,
        )
        .unwrap_or_else(|_| Camera::default_view(lo, hi, aspect, orthographic))
    }

    /// A camera on the `normal` side of the box `[lo, hi]` looking through its centre along
    /// `-normal`, `up` projected to be perpendicular, framing the projection of the box's
    /// eight corners for an image of aspect `width / height`: orthographic exactly, or
    /// perspective (vertical field of view `fov_y_deg`) standing back far enough that the
    /// framed extent fits at the box's nearest depth.
    ///
    /// # Errors
    /// [`Error::Parameter`] when `normal` is zero or not finite, `up` is parallel to it, or
    /// the box or field of view is invalid.
    pub fn framing(
        lo: Vec3,
        hi: Vec3,
        normal: Vec3,
        up: Vec3,
        aspect: f32,
        orthographic: bool,
        fov_y_deg: f32,
    ) -> Result<Camera> {
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(Error::parameter("camera: the box must be finite"));
        }
        let n = normal
            .try_normalize()
            .filter(|n| n.is_finite())
            .ok_or_else(|| Error::parameter(format!("view normal {normal} must be non-zero")))?;
        let f = -n;
        let right = f
            .cross(up)
            .try_normalize()
            .ok_or_else(|| Error::parameter("camera: up is parallel to the view direction"))?;
        let upv = right.cross(f);
        let centre = 0.5 * (lo + hi);
        let (mut ex, mut ey, mut ez) = (0.0f32, 0.0f32, 0.0f32);
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            ) - centre;
            ex = ex.max(c.dot(right).abs());
            ey = ey.max(c.dot(upv).abs());
            ez = ez.max(c.dot(n).abs());
        }
        let aspect = if aspect > 0.0 && aspect.is_finite() {
            aspect
        } else {
            1.0
        };
        // Every distance scales with the box, so a volume in any units (1e-30 or 1e30 per
        // voxel) is framed alike; a box of no extent still gets a positive view.
        let size = (hi - lo).abs().max_element();
        let half_h = ey.max(ex / aspect).max(size * 1e-6).max(f32::MIN_POSITIVE);
        let camera = if orthographic {
            Camera {
                eye: centre + n * (2.0 * ez + half_h),
                target: centre,
                up: upv,
                projection: Projection::Orthographic {
                    height: 2.0 * half_h,
                },
            }
        } else {
            if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
                return Err(Error::parameter(format!(
                    "camera: field of view {fov_y_deg} must be in (0, 180) degrees"
                )));
            }
            let t = (fov_y_deg.to_radians() * 0.5).tan();
            Camera {
                eye: centre + n * (half_h / t + ez),
                target: centre,
                up: upv,
                projection: Projection::Perspective { fov_y_deg },
            }
        };
        camera.validate()?;
        Ok(camera)
    }

    /// The camera with `eye`, `target` and `up` replaced where given. Without `up`, a view
    /// that has become parallel to the current up takes yt's up for its own direction
    /// ([`up_for`]), so an eye placed on an axis needs no up of its own. Not validated.
    #[must_use]
    pub fn with_overrides(
        mut self,
        eye: Option<Vec3>,
        target: Option<Vec3>,
        up: Option<Vec3>,
    ) -> Camera {
        if let Some(e) = eye {
            self.eye = e;
        }
        if let Some(t) = target {
            self.target = t;
        }
        match up {
            Some(u) => self.up = u,
            None => {
                // Directions only, normalised first: the squares of world lengths over- or
                // underflow f32 for volumes in centimetres or at 1e-30 per voxel.
                let parallel = match (unit(self.eye - self.target), unit(self.up)) {
                    (Some(b), Some(u)) => b.cross(u).length_squared() < 1e-12,
                    _ => true,
                };
                if parallel {
                    self.up = up_for(self.eye - self.target);
                }
            }
        }
        self
    }

    /// The camera magnified `zoom` times about its view centre: an orthographic view spans
    /// `1 / zoom` of its height, a perspective one narrows its field of view so that
    /// `tan(fov / 2)` shrinks `zoom` times (the eye stays where it is).
    ///
    /// # Errors
    /// [`Error::Parameter`] when `zoom` is not finite and > 0.
    pub fn zoomed(mut self, zoom: f32) -> Result<Camera> {
        if !(zoom.is_finite() && zoom > 0.0) {
            return Err(Error::parameter(format!(
                "zoom {zoom} must be finite and > 0"
            )));
        }
        self.projection = match self.projection {
            Projection::Orthographic { height } => Projection::Orthographic {
                height: height / zoom,
            },
            Projection::Perspective { fov_y_deg } => Projection::Perspective {
                fov_y_deg: 2.0
                    * ((fov_y_deg.to_radians() * 0.5).tan() / zoom)
                        .atan()
                        .to_degrees(),
            },
        };
        // A zoom far out of range overflows the view (it was reported as a bad height).
        match self.projection {
            Projection::Orthographic { height } if !(height > 0.0 && height.is_finite()) => {
                return Err(Error::parameter(format!(
                    "zoom {zoom} is out of range for this view (it leaves an orthographic \
                     height of {height})"
                )));
            }
            Projection::Perspective { fov_y_deg } if fov_y_deg <= 0.0 => {
                return Err(Error::parameter(format!(
                    "zoom {zoom} is out of range for this view (it leaves a field of view \
                     of {fov_y_deg} degrees)"
                )));
            }
            _ => {}
        }
        self.validate()?;
        Ok(self)
    }

    /// The camera's orthonormal frame `(forward, right, up)`: forward from eye to target,
    /// right = forward x up, up = right x forward (a degenerate camera gives +z, +x, +y).
    /// Every backend builds its rays from this frame.
    #[must_use]
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = unit(self.target - self.eye).unwrap_or(Vec3::Z);
        let r = f.cross(self.up).try_normalize().unwrap_or(Vec3::X);
        (f, r, r.cross(f))
    }

    /// World size of one pixel of an image `height` pixels high where the box `[lo, hi]` is
    /// nearest to the camera: the orthographic view's height over `height`; for a perspective
    /// camera `2 d tan(fov / 2) / height` at the distance `d` from the eye to the box (0 when
    /// the eye is inside it). Levels of detail are chosen from this.
    #[must_use]
    pub fn pixel_footprint(&self, lo: Vec3, hi: Vec3, height: u32) -> f32 {
        let h = height.max(1) as f32;
        match self.projection {
            Projection::Orthographic { height: world } => world / h,
            Projection::Perspective { fov_y_deg } => {
                let d = (self.eye.clamp(lo.min(hi), lo.max(hi)) - self.eye)
                    .as_dvec3()
                    .length() as f32;
                2.0 * d * (fov_y_deg.to_radians() * 0.5).tan() / h
            }
        }
    }

    /// The rays through the centres of every `every`-th pixel of every `every`-th row, in
    /// render order, as world-space `(origin, direction)`: the sparse sample of a view that
    /// out-of-core renders prefetch bricks along.
    #[must_use]
    pub fn sparse_rays(&self, width: u32, height: u32, every: u32) -> Vec<(Vec3, Vec3)> {
        let every = every.max(1) as usize;
        let mut rays = Vec::new();
        for y in (0..height).step_by(every) {
            for x in (0..width).step_by(every) {
                let r = self.ray(x as f32 + 0.5, y as f32 + 0.5, width, height);
                rays.push((r.origin, r.dir));
            }
        }
        rays
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

/// yt's image axes for an observer on the `normal` side: along `z` x right and y up, along
/// `x` y right and z up, along `y` z right and x up (also for the negative axes, seen from
/// behind); any other normal gets +z as up (+y when the normal is within 8 degrees of z).
#[must_use]
pub fn up_for(normal: Vec3) -> Vec3 {
    let n = unit(normal).unwrap_or(Vec3::Z);
    let a = n.abs();
    if a.abs_diff_eq(Vec3::Z, 1e-6) {
        Vec3::Y
    } else if a.abs_diff_eq(Vec3::X, 1e-6) {
        Vec3::Z
    } else if a.abs_diff_eq(Vec3::Y, 1e-6) {
        Vec3::X
    } else if a.z > 0.99 {
        Vec3::Y
    } else {
        Vec3::Z
    }
}

/// A named view: the observer on the +axis side (`x`, `y`, `z`, yt's axis projections), on
/// the -axis side (`-x`, `-y`, `-z`: the same view from behind, mirrored) or on the (1, 1, 1)
/// diagonal (`iso`, z up). Image axes follow [`up_for`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// Observer at +x: y right, z up.
    X,
    /// Observer at +y: z right, x up.
    Y,
    /// Observer at +z: x right, y up (the default view).
    Z,
    /// Observer at -x.
    NegX,
    /// Observer at -y.
    NegY,
    /// Observer at -z.
    NegZ,
    /// Observer on the (1, 1, 1) diagonal, z up.
    Iso,
}

impl View {
    /// Every view, in the order of [`View::NAMES`].
    pub const ALL: [View; 7] = [
        View::X,
        View::Y,
        View::Z,
        View::NegX,
        View::NegY,
        View::NegZ,
        View::Iso,
    ];
    /// The spellings of [`View::ALL`].
    pub const NAMES: [&'static str; 7] = ["x", "y", "z", "-x", "-y", "-z", "iso"];

    /// The unit direction from the target towards the observer.
    #[must_use]
    pub fn normal(self) -> Vec3 {
        match self {
            View::X => Vec3::X,
            View::Y => Vec3::Y,
            View::Z => Vec3::Z,
            View::NegX => -Vec3::X,
            View::NegY => -Vec3::Y,
            View::NegZ => -Vec3::Z,
            View::Iso => Vec3::ONE.normalize(),
        }
    }

    /// Its spelling.
    #[must_use]
    pub fn name(self) -> &'static str {
        Self::NAMES[Self::ALL.iter().position(|&v| v == self).unwrap_or(0)]
    }
}

impl std::str::FromStr for View {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let t = s.trim().to_ascii_lowercase();
        let t = t.strip_prefix('+').unwrap_or(&t);
        Self::NAMES
            .iter()
            .position(|&n| n == t)
            .map(|i| Self::ALL[i])
            .ok_or_else(|| {
                Error::parameter(format!(
                    "view '{s}': expected one of {}",
                    Self::NAMES.join(", ")
                ))
            })
    }
}

impl std::fmt::Display for View {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A half-open world box `lo <= p < hi` (per axis) that restricts a render to the samples
/// inside it, for distributed (sort-last) rendering: boxes that tile space give every sample
/// point of a ray to exactly one box. Faces may be infinite (`-inf` / `+inf`), so the boxes
/// at the domain's edge take everything beyond it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClipBox {
    /// Lower corner (inclusive).
    pub lo: Vec3,
    /// Upper corner (exclusive).
    pub hi: Vec3,
}

impl ClipBox {
    /// The box taking all of space.
    pub const ALL: Self = Self {
        lo: Vec3::splat(f32::NEG_INFINITY),
        hi: Vec3::splat(f32::INFINITY),
    };

    /// Whether `p` is inside: `lo <= p < hi` on every axis.
    #[must_use]
    #[inline]
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmplt(self.hi).all()
    }

    /// The ray parameters `[t0, t1]` where `ray` is inside this box intersected with the
    /// closed box `[lo, hi]` (the render domain), widened by `margin` on both sides; `None`
    /// if it misses. A conservative range: callers still test each sample with
    /// [`ClipBox::contains`].
    #[must_use]
    pub fn ray_range(&self, ray: &Ray, lo: Vec3, hi: Vec3, margin: f32) -> Option<(f32, f32)> {
        let lo = lo.max(self.lo);
        let hi = hi.min(self.hi);
        if lo.cmpgt(hi).any() {
            return None;
        }
        let (t0, t1) = ray.clip_box(lo, hi)?;
        Some(((t0 - margin).max(0.0), t1 + margin))
    }
}
