//! The spellings of the crate's enums (the macros are `blueshift_camera::named_enum` and
//! `serde_via_str`): every spelling round-trips, a bad one lists the accepted.

#[cfg(test)]
mod tests {
    use crate::{BandShift, ColourMatrix, Error, Exposure, SpectralAxis, SpectralIntegrator};

    /// `text` parses to `v`, prints as `text`, and goes through serde_json as the string.
    fn trip<T>(text: &str, v: T)
    where
        T: PartialEq
            + std::fmt::Debug
            + std::fmt::Display
            + std::str::FromStr<Err = Error>
            + serde::Serialize
            + for<'de> serde::Deserialize<'de>,
    {
        assert_eq!(text.parse::<T>().unwrap(), v, "{text}");
        assert_eq!(v.to_string(), text);
        let json = serde_json::to_string(&v).unwrap();
        assert_eq!(json, format!("\"{text}\""));
        assert_eq!(serde_json::from_str::<T>(&json).unwrap(), v);
    }

    #[test]
    fn every_spelling_round_trips_and_bad_ones_list_the_accepted() {
        assert_eq!(ColourMatrix::NAMES, ["srgb", "cie"]);
        trip("srgb", ColourMatrix::Srgb);
        trip("cie", ColourMatrix::CieRgbEq10);
        assert_eq!(
            "rgb".parse::<ColourMatrix>().unwrap_err().to_string(),
            "colour matrix: unknown 'rgb' (srgb, cie)"
        );
        assert_eq!(BandShift::NAMES, ["banded", "banded-ec"]);
        trip("banded", BandShift::Nearest);
        trip("banded-ec", BandShift::EnergyConserving);
        assert_eq!(
            "ec".parse::<BandShift>().unwrap_err().to_string(),
            "band shift: unknown 'ec' (banded, banded-ec)"
        );
        trip("pwl", SpectralIntegrator::PiecewiseLinear);
        for (text, bands, shift) in [
            ("banded:64", 64, BandShift::Nearest),
            ("banded-ec:48", 48, BandShift::EnergyConserving),
            ("banded:1000000", 1_000_000, BandShift::Nearest),
        ] {
            trip(text, SpectralIntegrator::Banded { bands, shift });
        }
        for bad in ["banded", "bands:4", "banded:x", "banded:0", "pw"] {
            let e = bad.parse::<SpectralIntegrator>().unwrap_err().to_string();
            assert!(
                e.contains("pwl, banded:N or banded-ec:N") || e.contains("N must"),
                "{e}"
            );
            let e = serde_json::from_str::<SpectralIntegrator>(&format!("\"{bad}\""))
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("integrator '{bad}'")), "{e}");
        }
        trip("per-pixel", Exposure::PerPixel);
        trip("p99", Exposure::Percentile(99.0));
        trip("p99.5", Exposure::Percentile(99.5));
        trip("0.25", Exposure::Fixed(0.25));
        trip("3", Exposure::Fixed(3.0));
        assert_eq!(
            " p50 ".parse::<Exposure>().unwrap(),
            Exposure::Percentile(50.0)
        );
        assert_eq!(
            "p101".parse::<Exposure>().unwrap_err().to_string(),
            "invalid parameter: exposure p101: a percentile pNN needs NN in [0, 100]"
        );
        assert_eq!(
            "0".parse::<Exposure>().unwrap_err().to_string(),
            "invalid parameter: exposure 0: expected a number > 0, pNN (percentile) or per-pixel"
        );
        trip("vrad", SpectralAxis::RadioVelocity);
        trip("vopt", SpectralAxis::OpticalVelocity);
        trip("wave", SpectralAxis::Wavelength);
        assert!(
            "freq"
                .parse::<SpectralAxis>()
                .unwrap_err()
                .to_string()
                .contains("use vrad, vopt or wave")
        );
    }
}
