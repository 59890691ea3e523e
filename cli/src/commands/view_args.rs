//! The camera flags `render` and `doppler` share: a view preset, eye / target / up and zoom.

use anyhow::{Result, bail};
use blueshift_camera::{Camera, View};
use glam::Vec3;

/// Camera flags (world units; the volume's box frames the view).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ViewArgs {
    /// View preset: x | y | z | -x | -y | -z | iso. The observer sits on that side of the
    /// volume with yt's image axes (z: x right, y up; x: y right, z up; y: z right, x up;
    /// -AXIS: the same seen from behind; iso: from the (1,1,1) diagonal, z up), framing the
    /// volume [default: z].
    #[arg(long, allow_hyphen_values = true)]
    pub view: Option<String>,
    /// Camera position X,Y,Z in world units [default: the view's, framing the volume].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub eye: Option<Vec<f32>>,
    /// Point looked at X,Y,Z in world units [default: the volume's centre].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub target: Option<Vec<f32>>,
    /// Up direction X,Y,Z [default: the view's: +y for z, +z for x, +x for y].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub up: Option<Vec<f32>>,
    /// Magnification about the view centre [default: 1].
    #[arg(long, allow_hyphen_values = true)]
    pub zoom: Option<f32>,
    /// A camera path: N frames orbiting the eye about the target, around the up direction,
    /// DEG degrees in all (default 360: equal steps, the last one step short of the first,
    /// so the sequence loops; positive is counter-clockwise seen from above). Every output
    /// becomes STEM_kkkk.EXT; `--distributed frames` spreads the frames over the ranks.
    #[arg(long, value_name = "N[:DEG]")]
    pub orbit: Option<String>,
    /// The angle of the orbit frame being rendered, degrees (set per frame by the driver).
    #[arg(skip)]
    pub orbit_deg: Option<f32>,
}

/// Three finite numbers from a comma-separated flag.
pub fn triple(v: &[f32], what: &str) -> Result<[f32; 3]> {
    match v {
        [a, b, c] if v.iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => bail!("{what}: expected three finite numbers X,Y,Z, got {v:?}"),
    }
}

impl ViewArgs {
    /// The view preset (`None` when not given).
    pub fn preset(&self) -> Result<Option<View>> {
        self.view
            .as_deref()
            .map(|v| {
                v.parse::<View>().map_err(|e| match e {
                    blueshift_camera::Error::Parameter(m) => anyhow::anyhow!("--{m}"),
                    other => anyhow::anyhow!("--view: {other}"),
                })
            })
            .transpose()
    }

    /// `--eye`, `--target`, `--up` as arrays.
    pub fn points(&self) -> Result<[Option<[f32; 3]>; 3]> {
        let t = |v: &Option<Vec<f32>>, what| v.as_deref().map(|v| triple(v, what)).transpose();
        Ok([
            t(&self.eye, "--eye")?,
            t(&self.target, "--target")?,
            t(&self.up, "--up")?,
        ])
    }

    /// Applies eye, target, up and zoom over `cam` (an eye without `--up` whose view is
    /// parallel to the current up takes yt's up for its own direction).
    pub fn apply_over(&self, cam: Camera) -> Result<Camera> {
        let [eye, target, up] = self.points()?;
        let mut cam = cam.with_overrides(
            eye.map(Vec3::from),
            target.map(Vec3::from),
            up.map(Vec3::from),
        );
        if let Some(z) = self.zoom {
            cam = cam.zoomed(z).map_err(|e| anyhow::anyhow!("--{e}"))?;
        }
        cam.validate()
            .map_err(|e| anyhow::anyhow!("--eye/--target/--up: {e}"))?;
        self.orbited(cam)
    }

    /// `cam` turned to this orbit frame's angle (unchanged outside an orbit): the eye
    /// rotates about the target around `up`, which stays as it is.
    pub fn orbited(&self, cam: Camera) -> Result<Camera> {
        let Some(deg) = self.orbit_deg else {
            return Ok(cam);
        };
        let axis = cam.up.normalize_or_zero();
        if axis == Vec3::ZERO {
            bail!("--orbit: the camera's up direction is zero");
        }
        let turn = glam::Quat::from_axis_angle(axis, deg.to_radians());
        let cam = Camera {
            eye: cam.target + turn * (cam.eye - cam.target),
            ..cam
        };
        cam.validate()
            .map_err(|e| anyhow::anyhow!("--orbit: {e}"))?;
        Ok(cam)
    }

    /// The frame angles of `--orbit N[:DEG]` (degrees), `None` without it.
    pub fn orbit_angles(&self) -> Result<Option<Vec<f32>>> {
        let Some(spec) = self.orbit.as_deref() else {
            return Ok(None);
        };
        let bad = || {
            anyhow::anyhow!(
                "--orbit {spec:?}: expected N or N:DEG (N frames from 1 to 100000, DEG finite)"
            )
        };
        let (n, deg) = match spec.split_once(':') {
            Some((n, d)) => (n, d.trim().parse::<f32>().map_err(|_| bad())?),
            None => (spec, 360.0),
        };
        let n: usize = n.trim().parse().map_err(|_| bad())?;
        if !(1..=100_000).contains(&n) || !deg.is_finite() {
            return Err(bad());
        }
        Ok(Some(
            (0..n)
                .map(|k| (f64::from(deg) * k as f64 / n as f64) as f32)
                .collect(),
        ))
    }
}
