//! [`TonemapSession`]: one HDR image cleaned once, tone-mapped with any operator.
//!
//! The engines' session shape (build once, edit, run again), without the
//! `blueshift_camera::Session` trait: tonemap is a base crate and imports no other
//! workspace crate. The GPU crate's tone mapping takes the same [`CleanImage`].

use image::Rgb32FImage;

use crate::ops::Operator;
use crate::sanitize::CleanImage;
use crate::{Error, Result};

/// An HDR image prepared once (the dirty-input rule applied, luminance and statistics
/// computed: [`CleanImage`]) and an operator; [`TonemapSession::set_operator`] changes the
/// operator or its parameters without cleaning the image again.
#[derive(Clone, Debug)]
pub struct TonemapSession {
    clean: CleanImage,
    op: Operator,
}

impl TonemapSession {
    /// Cleans `image` once and checks `op`'s parameters.
    ///
    /// # Errors
    /// [`Error::EmptyImage`] for a 0-pixel image; [`Error::Parameter`] for a bad operator.
    pub fn new(image: Rgb32FImage, op: Operator) -> Result<Self> {
        if image.width() == 0 || image.height() == 0 {
            return Err(Error::EmptyImage);
        }
        op.validate()?;
        Ok(Self {
            clean: CleanImage::from_image(image),
            op,
        })
    }

    /// The cleaned image, its luminance and statistics.
    #[must_use]
    pub fn clean(&self) -> &CleanImage {
        &self.clean
    }

    /// The operator.
    #[must_use]
    pub fn operator(&self) -> &Operator {
        &self.op
    }

    /// Replaces the operator (nothing else is recomputed).
    ///
    /// # Errors
    /// [`Error::Parameter`] for a bad operator (the session keeps its old one).
    pub fn set_operator(&mut self, op: Operator) -> Result<()> {
        op.validate()?;
        self.op = op;
        Ok(())
    }

    /// The display image (linear, in [0, 1]), as [`Operator::apply`] gives it.
    ///
    /// # Errors
    /// As [`Operator::apply_clean`].
    pub fn run(&self) -> Result<Rgb32FImage> {
        self.op.apply_clean(&self.clean)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ops::{DragoParams, LinearParams};

    fn ramp() -> Rgb32FImage {
        Rgb32FImage::from_fn(16, 8, |x, y| {
            let v = 10f32.powf((x as f32 + 16.0 * y as f32) / 32.0 - 2.0);
            image::Rgb([v, 0.5 * v, 0.25 * v])
        })
    }

    #[test]
    fn session_equals_apply_and_an_operator_edit_equals_a_fresh_apply() {
        let img = ramp();
        let drago = Operator::Drago(DragoParams::default());
        let mut s = TonemapSession::new(img.clone(), drago.clone()).unwrap();
        assert_eq!(s.run().unwrap(), drago.apply(&img).unwrap());
        let lin = Operator::Linear(LinearParams {
            exposure_stops: 1.0,
            ..LinearParams::default()
        });
        s.set_operator(lin.clone()).unwrap();
        assert_eq!(s.run().unwrap(), lin.apply(&img).unwrap());
        assert!(matches!(
            TonemapSession::new(Rgb32FImage::new(0, 0), lin),
            Err(Error::EmptyImage)
        ));
    }
}
