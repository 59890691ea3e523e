//! Requests that would need unbounded work are refused up front, naming their setting.

/// A temperature whose radiance overflows f64 is refused up front, naming the temperature
/// (not the error bound), and in well under the time an adaptive subdivision would take.
#[test]
fn an_overflowing_temperature_is_named() {
    let e = blueshift_spectrum::Blackbody::new(1e300)
        .unwrap()
        .to_piecewise(380.0, 780.0, 1e-4)
        .unwrap_err();
    assert!(
        matches!(e, blueshift_spectrum::Error::Parameter { name, .. } if name.starts_with("temperature")),
        "{e}"
    );
    // A hot but representable black body still works.
    assert!(
        blueshift_spectrum::Blackbody::new(1e9)
            .unwrap()
            .to_piecewise(380.0, 780.0, 1e-4)
            .is_ok()
    );
}
