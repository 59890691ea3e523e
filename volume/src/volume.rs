//! Multi-channel volumes: named grids sharing one geometry.

use crate::grid::{AnyGrid, Geometry};
use crate::io::DiskType;
use crate::macrocell::Macrocells;
use crate::{Error, Result};

/// One named channel of a [`Volume`].
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// Channel name (`"density"`, `"temperature_k"`, `"velocity_m_per_s"`, `"scalars"`, ...).
    pub name: String,
    /// The voxels.
    pub grid: AnyGrid,
    /// The voxel type the data had on disk, if it came from a file. Writers use it to keep
    /// the original type (e.g. i16 CT data, held in memory as f32) when that is lossless.
    pub stored_as: Option<DiskType>,
}

/// Named channels sharing one [`Geometry`], e.g. the species densities, temperature and
/// velocity of a galaxy simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    geometry: Geometry,
    channels: Vec<Channel>,
}

impl Volume {
    /// An empty volume with `geometry`.
    pub fn new(geometry: Geometry) -> Result<Self> {
        geometry.validate()?;
        Ok(Volume {
            geometry,
            channels: Vec::new(),
        })
    }

    /// A one-channel volume.
    pub fn single(name: impl Into<String>, grid: impl Into<AnyGrid>) -> Result<Self> {
        let grid = grid.into();
        let mut v = Volume::new(*grid.geometry())?;
        v.push(name, grid)?;
        Ok(v)
    }

    /// Adds a channel; refuses a duplicate name or a grid with different dims. The grid's
    /// origin and spacing are replaced by the volume's.
    pub fn push(&mut self, name: impl Into<String>, grid: impl Into<AnyGrid>) -> Result<()> {
        self.push_channel(Channel {
            name: name.into(),
            grid: grid.into(),
            stored_as: None,
        })
    }

    /// Adds a channel with its on-disk type (see [`Volume::push`]).
    pub fn push_channel(&mut self, mut channel: Channel) -> Result<()> {
        if channel.grid.geometry().dims != self.geometry.dims {
            return Err(Error::parameter(format!(
                "channel '{}' has dims {:?}, the volume has {:?}",
                channel.name,
                channel.grid.geometry().dims,
                self.geometry.dims
            )));
        }
        if self.channel(&channel.name).is_some() {
            return Err(Error::parameter(format!(
                "duplicate channel name '{}'",
                channel.name
            )));
        }
        channel.grid.set_geometry(self.geometry)?;
        self.channels.push(channel);
        Ok(())
    }

    /// The shared geometry.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Replaces origin and spacing of the volume and all channels (dims must match).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        for c in &mut self.channels {
            c.grid.set_geometry(geometry)?;
        }
        self.geometry = geometry;
        Ok(())
    }

    /// The channels in insertion order (file order for readers).
    #[must_use]
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// Takes the channels out.
    #[must_use]
    pub fn into_channels(self) -> Vec<Channel> {
        self.channels
    }

    /// The channel called `name`.
    #[must_use]
    pub fn channel(&self, name: &str) -> Option<&Channel> {
        self.channels.iter().find(|c| c.name == name)
    }

    /// The grid of channel `name`, or [`Error::Parameter`] listing the names there are.
    pub fn grid(&self, name: &str) -> Result<&AnyGrid> {
        self.channel(name).map(|c| &c.grid).ok_or_else(|| {
            let names: Vec<&str> = self.channels.iter().map(|c| c.name.as_str()).collect();
            Error::parameter(format!(
                "no channel '{name}' (channels: {})",
                names.join(", ")
            ))
        })
    }

    /// Macrocells of every scalar channel (vector channels are skipped), in channel order,
    /// each paired with its channel name.
    pub fn macrocells(&self, k: usize) -> Result<Vec<(String, Macrocells)>> {
        self.channels
            .iter()
            .filter(|c| !c.grid.is_vector())
            .map(|c| Ok((c.name.clone(), Macrocells::build_any(&c.grid, k)?)))
            .collect()
    }

    /// Refuses NaN/Inf in any channel.
    pub fn reject_non_finite(&self) -> Result<()> {
        self.channels
            .iter()
            .try_for_each(|c| c.grid.reject_non_finite())
    }
}
