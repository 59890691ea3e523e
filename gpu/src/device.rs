//! One device-fallback rule for every backend: what `--device cpu|gpu|auto` runs where.
//!
//! Each backend answers "can the GPU run this?" with one `supports(...)` returning
//! `Result<(), Unsupported>` ([`crate::tracking::supports`], [`crate::doppler::supports`],
//! [`crate::tonemap::supports`], [`crate::relativity::supports`]); [`run_with_fallback`]
//! applies the rule every caller (the CLI, the viewer, Python) shares:
//! - `cpu`: the CPU;
//! - `gpu`: the shared adapter, or its error; a job the backend does not support is
//!   refused with [`Error::Unsupported`];
//! - `auto`: a hardware GPU (or the adapter `BLUESHIFT_GPU` forces) when there is one and it
//!   supports the job, else the CPU; a GPU failure that [`DeviceChoice::falls_back_on`]
//!   (limits, the loop limit, memory) runs the job on the CPU, with a note saying why.

use blueshift_camera::DeviceKind;

use crate::context::{DeviceChoice, GpuContext};
use crate::error::{Error, Result};

/// Why a GPU backend cannot run a job (the CPU can).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unsupported(pub String);

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<Unsupported> for Error {
    fn from(u: Unsupported) -> Self {
        Error::Unsupported(u.0)
    }
}

/// A job's result and where it ran.
#[derive(Clone, Debug)]
pub struct Ran<T> {
    /// The job's result.
    pub value: T,
    /// The device that produced it.
    pub device: DeviceKind,
    /// Why `auto` ran it on the CPU although a GPU was there (unsupported, over a limit).
    pub fallback: Option<String>,
}

/// Runs a job where `choice` says (see the module docs): `supported` is asked only when a
/// GPU is there, `on_gpu` runs the job on it, `on_cpu` on the CPU.
///
/// # Errors
/// `on_cpu`'s error; for `gpu`, no adapter, [`Error::Unsupported`] or `on_gpu`'s error; for
/// `auto`, `on_gpu`'s errors that do not fall back (invalid input, device lost, ...).
pub fn run_with_fallback<T, E: From<Error>>(
    choice: DeviceChoice,
    supported: impl FnOnce() -> std::result::Result<(), Unsupported>,
    on_gpu: impl FnOnce(&'static GpuContext) -> Result<T>,
    on_cpu: impl FnOnce() -> std::result::Result<T, E>,
) -> std::result::Result<Ran<T>, E> {
    let Some(ctx) = choice.context()? else {
        return on_cpu().map(|value| Ran {
            value,
            device: DeviceKind::Cpu,
            fallback: None,
        });
    };
    let why = match supported() {
        Err(why) if choice == DeviceChoice::Gpu => return Err(Error::from(why).into()),
        Err(why) => why.0,
        Ok(()) => match on_gpu(ctx) {
            Ok(value) => {
                return Ok(Ran {
                    value,
                    device: DeviceKind::Gpu,
                    fallback: None,
                });
            }
            Err(e) if choice.falls_back_on(&e) => e.to_string(),
            Err(e) => return Err(e.into()),
        },
    };
    on_cpu().map(|value| Ran {
        value,
        device: DeviceKind::Cpu,
        fallback: Some(why),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_choice_never_asks_the_gpu() {
        let r: std::result::Result<Ran<u8>, Error> = run_with_fallback(
            DeviceChoice::Cpu,
            || panic!("supported asked"),
            |_| panic!("gpu asked"),
            || Ok(7),
        );
        let r = r.unwrap();
        assert_eq!((r.value, r.device, r.fallback), (7, DeviceKind::Cpu, None));
    }

    #[test]
    fn gpu_choice_refuses_unsupported_and_auto_falls_back() {
        // Only meaningful with an adapter; without one `gpu` fails with NoAdapter.
        let gpu: std::result::Result<Ran<u8>, Error> = run_with_fallback(
            DeviceChoice::Gpu,
            || Err(Unsupported("shading".into())),
            |_| Ok(1),
            || Ok(2),
        );
        match crate::context::test_context() {
            Some(_) => assert!(matches!(gpu, Err(Error::Unsupported(w)) if w == "shading")),
            None => assert!(gpu.is_err()),
        }
        // auto: an over-limit failure on the GPU runs the job on the CPU, with the reason.
        let auto: Ran<u8> = run_with_fallback::<_, Error>(
            DeviceChoice::Auto,
            || Ok(()),
            |_| Err(Error::Unsupported("loop limit".into())),
            || Ok(2),
        )
        .unwrap();
        assert_eq!((auto.value, auto.device), (2, DeviceKind::Cpu));
        // A GPU error that is not a fit problem is returned, not hidden.
        let bad = run_with_fallback::<u8, Error>(
            DeviceChoice::Gpu,
            || Ok(()),
            |_| Err(Error::InvalidInput("nan".into())),
            || Ok(2),
        );
        assert!(bad.is_err());
    }
}
