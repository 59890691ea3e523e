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
        Ok(cam)
    }
}
