//! The moving observer of `render` and `doppler`: `--observer-velocity`, or `--beta` along
//! `--direction`, or a `--ramp` of speeds writing a frame sequence.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use blueshift_relativity::{MovingObserver, Velocity, parse_ramp};
use glam::{DVec3, Vec3};

/// Flags of a moving observer (relativistic aberration, Doppler and searchlight of an
/// observer flying through the volume).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ObserverArgs {
    /// The observer's velocity BETA_X,BETA_Y,BETA_Z relative to the volume, in units of c
    /// (|beta| < 1): every pixel's ray is aberrated into the volume's frame and what it sees
    /// is Doppler shifted by the observer's motion, composed with the gas's own.
    #[arg(long, value_name = "BX,BY,BZ", allow_hyphen_values = true,
          conflicts_with_all = ["beta", "ramp"])]
    pub observer_velocity: Option<String>,
    /// The observer's speed in units of c (|beta| < 1) along --direction.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "ramp")]
    pub beta: Option<f64>,
    /// Direction X,Y,Z of --beta or --ramp in the volume's frame [default: the view
    /// direction, flying into the picture].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub direction: Option<String>,
    /// A speed ramp START:END:FRAMES (for example 0:0.9:10) along --direction: frame k is
    /// written as STEM_kkkk.EXT for every output.
    #[arg(long, value_name = "START:END:FRAMES")]
    pub ramp: Option<String>,
}

fn parse_vec(flag: &str, s: &str) -> Result<DVec3> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<f64>()
                .with_context(|| format!("{flag} {s:?}: '{}' is not a number", c.trim()))
        })
        .collect::<Result<_>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(DVec3::new(*x, *y, *z)),
        _ => bail!("{flag} {s:?}: expected three finite numbers X,Y,Z"),
    }
}

impl ObserverArgs {
    /// The speeds of `--ramp`, checked (`None` without a ramp).
    pub fn ramp_speeds(&self) -> Result<Option<Vec<f64>>> {
        self.ramp
            .as_deref()
            .map(|r| parse_ramp(r).map_err(|e| anyhow::anyhow!("--ramp: {e}")))
            .transpose()
    }

    fn direction(&self, view: Vec3) -> Result<DVec3> {
        match &self.direction {
            Some(s) => parse_vec("--direction", s),
            None => Ok(view.as_dvec3()),
        }
    }

    /// The observer of a single frame (`--observer-velocity`, or `--beta` along
    /// `--direction`, or `speed` of a ramp frame along it); `None` without observer flags.
    /// `view` is the camera's view direction, the default `--direction`.
    pub fn observer(
        &self,
        view: Vec3,
        speed: Option<f64>,
        searchlight: bool,
    ) -> Result<Option<MovingObserver>> {
        let velocity = if let Some(s) = &self.observer_velocity {
            let b = parse_vec("--observer-velocity", s)?;
            Velocity::new(b).map_err(|e| anyhow::anyhow!("--observer-velocity: {e}"))?
        } else if let Some(b) = speed.or(self.beta) {
            let d = self.direction(view)?;
            Velocity::along(d, b).map_err(|e| {
                let flag = if speed.is_some() { "--ramp" } else { "--beta" };
                anyhow::anyhow!("{flag} {b} along --direction: {e}")
            })?
        } else {
            if self.direction.is_some() {
                bail!("--direction needs --beta or --ramp");
            }
            return Ok(None);
        };
        Ok(Some(MovingObserver {
            velocity,
            searchlight,
        }))
    }
}

/// The inputs of one command's frame sequence: its time series of snapshots (`--series`)
/// and how a snapshot becomes the frame's input.
pub struct Series<'a, A> {
    /// The snapshots, one frame each, in order.
    pub paths: &'a [PathBuf],
    /// Makes `path` the input of a copy of the arguments (the volume or the scene file).
    pub input: &'a dyn Fn(&mut A, &Path) -> Result<()>,
}

/// One frame of a sequence: what changes from the arguments.
enum FrameValue {
    Orbit(f64),
    Beta(f64),
    Snapshot(PathBuf),
}

/// Runs the frame sequence of `--series` (a time series of snapshots), `--orbit` (a camera
/// path) or `--ramp` (speeds), when one is given (`Ok(false)` when none is; two at once is
/// an error): `frame` once per frame on a copy of `args` whose outputs `outputs` renames
/// for frame `k` ([`frame_path`]) and whose input is that snapshot, or view turned, or
/// observer sped up, to that frame's value. Frames that `keep` declines (another rank's,
/// under `--distributed frames`) are skipped. Before the first frame renders, `check` is
/// given every frame's arguments and the inputs of the whole sequence (the `--series`
/// snapshots), once, so an output that cannot be written, or that is any frame's input,
/// stops the run before a partial sequence is written.
#[allow(clippy::too_many_arguments)]
pub fn run_frames<A: Clone>(
    args: &A,
    series: &Series<'_, A>,
    view: impl Fn(&mut A) -> &mut super::view_args::ViewArgs,
    observer: impl Fn(&mut A) -> &mut ObserverArgs,
    outputs: impl Fn(&mut A, usize),
    check: impl Fn(&[&A], &[&Path]) -> Result<()>,
    mut frame: impl FnMut(A) -> Result<()>,
    keep: impl Fn(usize) -> Result<bool>,
) -> Result<bool> {
    let mut probe = args.clone();
    let angles = view(&mut probe).orbit_angles()?;
    let speeds = observer(&mut probe).ramp_speeds()?;
    let given = [angles.is_some(), speeds.is_some(), !series.paths.is_empty()];
    if given.iter().filter(|g| **g).count() > 1 {
        bail!("give one of --series, --orbit and --ramp");
    }
    let values: Vec<FrameValue> = if let Some(a) = angles {
        a.into_iter()
            .map(|d| FrameValue::Orbit(f64::from(d)))
            .collect()
    } else if let Some(b) = speeds {
        b.into_iter().map(FrameValue::Beta).collect()
    } else if !series.paths.is_empty() {
        // A missing snapshot stops the run before any frame is written.
        for p in series.paths {
            if !p.exists() {
                bail!("--series: {}: no such file", p.display());
            }
        }
        series
            .paths
            .iter()
            .map(|p| FrameValue::Snapshot(p.clone()))
            .collect()
    } else {
        return Ok(false);
    };
    let mut frames = Vec::new();
    for (k, v) in values.into_iter().enumerate() {
        if !keep(k)? {
            continue;
        }
        let mut a = args.clone();
        outputs(&mut a, k);
        let said = match v {
            FrameValue::Orbit(v) => {
                let w = view(&mut a);
                w.orbit = None;
                w.orbit_deg = Some(v as f32);
                format!("frame {k}: orbit {v:.3} degrees")
            }
            FrameValue::Beta(v) => {
                let o = observer(&mut a);
                o.ramp = None;
                o.beta = Some(v);
                format!("frame {k}: beta {v:.4}")
            }
            FrameValue::Snapshot(p) => {
                (series.input)(&mut a, &p)?;
                format!("frame {k}: {}", p.display())
            }
        };
        frames.push((said, a));
    }
    let snapshots: Vec<&Path> = series.paths.iter().map(PathBuf::as_path).collect();
    let all: Vec<&A> = frames.iter().map(|(_, a)| a).collect();
    check(&all, &snapshots)?;
    for (said, a) in frames {
        errln!("{said}");
        frame(a)?;
    }
    Ok(true)
}

/// Frame `k`'s path for `path`: `STEM_kkkk.EXT` beside it.
#[must_use]
pub fn frame_path(path: &Path, k: usize) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match path.extension() {
        Some(e) => format!("{stem}_{k:04}.{}", e.to_string_lossy()),
        None => format!("{stem}_{k:04}"),
    };
    path.with_file_name(name)
}
