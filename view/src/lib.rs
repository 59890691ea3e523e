//! The interactive viewer of blueshift: a local web server that streams progressive renders
//! of a session to a browser page and takes edits back over a WebSocket.
//!
//! # Where do I start?
//! Build a [`Source`] (a tracking scene, a Doppler scene, a relativistic observer's
//! environment or an HDR image, each with what the engine session needs), a [`Config`]
//! (address, save folder), then [`Server::bind`] and [`Server::run`]. The `blueshift view`
//! command of the CLI does exactly that. The protocol is in `view/PROTOCOL.md`; the page
//! (plain ES modules and canvas, no build step) is embedded from `view/assets/`.
//!
//! Each WebSocket connection (each browser tab) gets its own worker thread and its own
//! engine session, so several tabs see their own edits. An edit cancels the running pass at
//! once (the engines poll [`blueshift_camera::Observer::cancelled`] between rows and
//! passes); the worker then renders a quarter-resolution 1-spp preview (then a half-resolution one for images of 256x256 or more) and refines at full
//! resolution, sending every pass as an 8-bit PNG tone-mapped on the server. Only the newest
//! frame waits for the socket: frames never queue up behind a slow page.
//!
//! # Security
//! The server binds 127.0.0.1 unless told otherwise; every URL carries a random 128-bit
//! token as its first path segment; a `Host` or `Origin` header naming another host is
//! refused (DNS rebinding); messages are limited to 1 MiB and validated; the only files it
//! writes or reads on request are in the save folder.
//!
//! # Glossary
//! | paper term | here |
//! |---|---|
//! | interactive TF editing while the volume re-renders (HDR VolVis section 5) | the `tf` message: only that channel's majorants are rebuilt |
//! | progressive accumulation (MDWT) | the refinement passes after the preview |
//! | pixel spectrum and its step-by-step accumulation (Doppler paper Figs. 8, 9) | the `pick` and `trace` messages |

mod assets;
pub mod display;
mod error;
mod modes;
mod protocol;
mod server;
mod worker;

pub use error::{Error, Result};
pub use modes::{
    DopplerSource, HdrSource, MAX_VIEW_PIXELS, PanelFn, RelativitySource, Source, TrackingSource,
};
pub use server::{Config, Running, Server, allowed_host, new_token};

/// Largest WebSocket message the server accepts, bytes.
pub const MAX_MESSAGE_BYTES: usize = 1 << 20;
