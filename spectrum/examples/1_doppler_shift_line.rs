//! H-alpha from gas moving at +-1,000 km/s: where the line lands under the classical and the
//! relativistic model, and how a band representation blurs it.
//!
//!     cargo run -p blueshift-spectrum --example 1_doppler_shift_line

use blueshift_spectrum::*;

fn main() -> Result<()> {
    let line = EmissionLine::new(656.28, 1.0)?;
    let profile = LineProfile::Box { width_nm: 0.2 };
    let spectrum = line.to_piecewise(profile)?;
    for v in [-1.0e6, 0.0, 1.0e6] {
        for model in [DopplerModel::Classical, DopplerModel::Relativistic] {
            let s = WavelengthShift::from_radial_velocity(model, v)?;
            let seen = spectrum.shifted(s, RadiometricTransform::None);
            let (a, b) = seen.support_nm().expect("non-empty");
            println!(
                "v = {v:+.0e} m/s {model:?}: line at {:.4} nm (s = {:.8})",
                0.5 * (a + b),
                s.value()
            );
        }
    }
    // 40 bands of 11.75 nm cannot see a 2.2 nm shift at all.
    let layout = BandLayout::new(360.0, 830.0, 40)?;
    let banded = Banded::projected(layout, &spectrum);
    let shifted = banded.shift_nearest(WavelengthShift::classical(1.0e6)?);
    println!(
        "banded N=40: line band {} -> {}",
        argmax(banded.values()),
        argmax(shifted.values())
    );
    Ok(())
}

fn argmax(v: &[f64]) -> usize {
    v.iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0, |(i, _)| i)
}
