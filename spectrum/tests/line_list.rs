//! Line lists: the header is required, and adding many lines in one sweep gives the spectrum
//! adding them one by one gives.

use blueshift_spectrum::{EmissionLine, LineProfile, PiecewiseLinear, add_lines, parse_line_list};

#[test]
fn the_header_names_the_columns() {
    for text in [
        "500,1\n",
        "lambda,intensity\n500,1\n",
        "wavelength_nm,flux\n500,1\n",
    ] {
        let msg = parse_line_list(text, "t.csv").unwrap_err().to_string();
        assert!(
            msg.contains("wavelength_nm")
                && msg.contains("relative_intensity")
                && msg.contains("t.csv"),
            "{msg}"
        );
    }
    let a = parse_line_list("wavelength_nm,relative_intensity\n656.3,2\n", "a").unwrap();
    let b = parse_line_list(
        "# c\nrelative_intensity,note,wavelength_nm\n2,x,656.3\n",
        "b",
    )
    .unwrap();
    assert_eq!(a, b);
    // A row with a field the header does not name (a shifted or unnamed column) is refused.
    let msg = parse_line_list("wavelength_nm,relative_intensity\n656.3,2,7\n", "e.csv")
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("e.csv") && msg.contains("expected 2 columns, found 3"),
        "{msg}"
    );
    // Empty fields at the end of a row are no columns.
    let c = parse_line_list("wavelength_nm,relative_intensity\n656.3,2,\n", "c").unwrap();
    assert_eq!(a, c);
}

#[test]
fn the_sweep_matches_one_by_one() {
    // Overlapping lines, touching ends and repeated centres, on a black-body-like base.
    let lines: Vec<EmissionLine> = (0..500)
        .map(|i| {
            EmissionLine::new(450.0 + f64::from(i % 97) * 0.37, 1.0 + f64::from(i % 5)).unwrap()
        })
        .collect();
    for profile in [
        LineProfile::Box { width_nm: 2.0 },
        LineProfile::Triangle { fwhm_nm: 1.5 },
    ] {
        let mut base = PiecewiseLinear::new();
        base.add_trapezoid(380.0, 780.0, 1.0, 3.0).unwrap();
        let mut one = base.clone();
        for l in &lines {
            l.add_to(&mut one, profile, 0.5).unwrap();
        }
        let mut swept = base.clone();
        add_lines(&mut swept, &lines, profile, 0.5).unwrap();
        for k in 0..40_000 {
            let x = 379.0 + f64::from(k) * 0.01;
            let (a, b) = (one.eval(x), swept.eval(x));
            assert!(
                (a - b).abs() <= 1e-9 * a.abs().max(1.0),
                "{profile:?} at {x}: {a} vs {b}"
            );
        }
        assert!((one.total() - swept.total()).abs() <= 1e-9 * one.total());
    }
}
