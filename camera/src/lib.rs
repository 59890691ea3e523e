//! # blueshift-camera: cameras, rays and render sessions
//!
//! The small pieces every blueshift engine shares, so that tracking, Doppler, relativity,
//! tone mapping and their GPU backends agree on them:
//! - [`Camera`] (perspective or orthographic look-at), [`Projection`], [`Ray`] with slab
//!   ray-box clipping, and [`Camera::default_view`];
//! - the render-session shape ([`Session`], [`Observer`], [`Progress`], [`CancelToken`]):
//!   a session is built once from (scene, settings, device), runs progressively under one
//!   observer (progress, the current image, a noise estimate, cancel) and can be run again
//!   after an edit without rebuilding what the edit did not touch.
//!
//! ## Orientation
//! Right-handed world. A camera looks from `eye` towards `target` with `up` roughly up;
//! image x grows along `forward x up` (the camera's right), image y grows downwards (row 0
//! is the top). The default view is yt's: the observer on the +z side looking towards -z,
//! world +x to the right and +y up, so a voxel at (+x, +y) lands top-right in every
//! renderer, cube and map; [`View`] names the other axis views (yt's image axes, see
//! [`up_for`]). Ray directions are unit vectors, so a ray parameter is a world length.
//!
//! ## Where do I start?
//! - [`Camera::default_view`] frames a box; [`Camera::ray`] gives the ray through a pixel.
//! - Engines implement [`Session`]; callers pass an [`Observer`] ([`Silent`],
//!   [`OnProgress`] or their own) to [`Session::run`].

pub mod camera;
mod error;
mod names;
pub mod session;

pub use camera::{Camera, ClipBox, DEFAULT_FOV_Y_DEG, Projection, Ray, View, unit, up_for};
pub use error::{Error, Result};
pub use session::{
    CancelToken, DeviceKind, Observer, OnProgress, Progress, ProgressOnly, Session, Silent,
    single_pass_done,
};
