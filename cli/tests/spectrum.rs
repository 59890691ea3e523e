//! `blueshift spectrum` from the outside: JSON keys and values, files, errors.

use std::process::Command;

fn blueshift() -> Command {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = blueshift().args(args).arg("--json").output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn json_has_xyz_xy_and_linear_srgb_consistent_with_each_other() {
    let v = json(&["spectrum", "--blackbody", "6500"]);
    let xyz: Vec<f64> = v["xyz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let xy: Vec<f64> = v["xy"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let rgb: Vec<f64> = v["srgb_linear"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!((xyz.len(), xy.len(), rgb.len()), (3, 2, 3));
    let sum: f64 = xyz.iter().sum();
    assert!((xy[0] - xyz[0] / sum).abs() < 1e-12 && (xy[1] - xyz[1] / sum).abs() < 1e-12);
    // A 6500 K black body lies near the D65 white point (x 0.3135, y 0.3236; CIE 15 Planckian
    // locus): far from any saturated colour.
    assert!(
        (xy[0] - 0.3135).abs() < 2e-3 && (xy[1] - 0.3236).abs() < 2e-3,
        "{xy:?}"
    );
    // The library's exact XYZ of its 1e-4 approximation agrees with the 1 nm summation to 3e-4.
    let bb = blueshift_spectrum::Blackbody::new(6500.0).unwrap().xyz();
    for (a, b) in xyz.iter().zip(bb.to_array()) {
        assert!((a - b).abs() / b < 3e-4, "{a} vs {b}");
    }
}

#[test]
fn radial_velocity_shift_moves_lines_by_v_over_c() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("s.csv");
    let v = 1.0e7; // 10,000 km/s: H-alpha moves by 21.9 nm
    let out = blueshift()
        .args([
            "spectrum",
            "--lines",
            "H",
            "--radial-velocity",
            &v.to_string(),
            "--line-width",
            "0.5",
            "--csv",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("wavelength_nm,value"));
    // The strongest feature is H-alpha: find the plateau.
    let pts: Vec<(f64, f64)> = lines
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    let max = pts.iter().map(|p| p.1).fold(0.0, f64::max);
    let on: Vec<f64> = pts.iter().filter(|p| p.1 == max).map(|p| p.0).collect();
    let centre = 0.5 * (on[0] + on[on.len() - 1]);
    let expect = 656.2816 * (1.0 + v / 299_792_458.0);
    assert!((centre - expect).abs() < 1e-6, "{centre} vs {expect}");
}

#[test]
fn plot_is_a_png() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("s.png");
    let out = blueshift()
        .args([
            "spectrum",
            "--blackbody",
            "3000",
            "--lines",
            "H,He,C",
            "--line-strength",
            "100",
            "--shift",
            "1.05",
            "--plot",
        ])
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (1000, 600));
}

/// The tallest run of pixels of exactly `colour` in any one column of the PNG.
fn tallest_column(img: &image::RgbImage, colour: [u8; 3]) -> u32 {
    (0..img.width())
        .map(|x| {
            (0..img.height())
                .filter(|&y| img.get_pixel(x, y).0 == colour)
                .count() as u32
        })
        .max()
        .unwrap_or(0)
}

#[test]
fn a_narrow_shifted_line_is_drawn_full_height_in_the_plot() {
    // One H-beta box 0.02 nm wide (a fraction of a pixel at 1000 px over 470 nm), shifted
    // by 3e6 m/s: the plot's y range is the box height, so its box must draw a vertical
    // stroke over most of the plot's height, in the rest frame (grey) and observed (blue).
    // Plotters filled the whole polyline as one polygon, in which such a spike had no area.
    let dir = tempfile::tempdir().unwrap();
    let list = dir.path().join("hb.csv");
    std::fs::write(&list, "wavelength_nm,relative_intensity\n486.135,1\n").unwrap();
    let png = dir.path().join("hb.png");
    let csv = dir.path().join("hb_obs.csv");
    let out = blueshift()
        .args(["spectrum", "--line-list"])
        .arg(&list)
        .args(["--line-width", "0.02", "--radial-velocity", "3e6", "--csv"])
        .arg(&csv)
        .arg("--plot")
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The CSV (the plotted polyline) holds the exact shifted box edges.
    let s = 1.0 + 3e6 / 299_792_458.0;
    let text = std::fs::read_to_string(&csv).unwrap();
    let xs: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    for edge in [(486.135 - 0.01) * s, (486.135 + 0.01) * s] {
        assert!(
            xs.iter().any(|x| (x - edge).abs() < 1e-9),
            "edge {edge} missing from {xs:?}"
        );
    }
    let img = image::open(&png).unwrap().to_rgb8();
    let plot_height = img.height() - 100;
    let blue = tallest_column(&img, [20, 60, 200]);
    let grey = tallest_column(&img, [160, 160, 160]);
    assert!(blue > plot_height * 3 / 4, "observed line {blue} px tall");
    assert!(grey > plot_height * 3 / 4, "rest-frame line {grey} px tall");
}

#[test]
fn bad_input_is_a_one_line_error_and_exit_code_1() {
    for args in [
        vec!["spectrum", "--blackbody", "-5"],
        vec!["spectrum", "--blackbody", "0"],
        vec!["spectrum", "--blackbody", "NaN"],
        vec!["spectrum", "--blackbody", "5000", "--range", "800:400"],
        vec!["spectrum", "--lines", "Fe"],
        vec![
            "spectrum",
            "--blackbody",
            "5000",
            "--radial-velocity",
            "3e8",
            "--doppler",
            "relativistic",
        ],
        vec!["spectrum", "--blackbody", "5000", "--shift", "0"],
        vec!["spectrum"],
    ] {
        let out = blueshift().args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with("blueshift:"), "{err}");
    }
}

#[test]
fn malformed_line_list_names_file_and_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let list = dir.path().join("lines.csv");
    std::fs::write(&list, "wavelength_nm,relative_intensity\n500,1\n510,x\n").unwrap();
    let csv = dir.path().join("out.csv");
    let out = blueshift()
        .arg("spectrum")
        .arg("--line-list")
        .arg(&list)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("lines.csv") && err.contains("line 3"), "{err}");
    assert!(!csv.exists());
}

#[test]
fn csv_round_trips_through_the_library_reader() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("s.csv");
    let out = blueshift()
        .args([
            "spectrum",
            "--blackbody",
            "4000",
            "--lines",
            "He",
            "--line-strength",
            "500",
            "--radial-velocity",
            "-2e6",
            "--json",
            "--csv",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let s = blueshift_spectrum::PiecewiseLinear::read_csv(&csv).unwrap();
    let xyz = blueshift_spectrum::Cmf::cie1931_2deg()
        .xyz_of(&s)
        .to_array();
    for (c, x) in xyz.iter().enumerate() {
        let want = v["xyz"][c].as_f64().unwrap();
        assert!((x - want).abs() <= 1e-9 * want, "{x} vs {want}");
    }
    let integral = v["integral"].as_f64().unwrap();
    assert!((s.total() - integral).abs() <= 1e-9 * integral);
}

/// Intensities near f64's end overflow the integral and the colour: one line and exit 1
/// (it printed `integral inf`, `linear sRGB NaN NaN NaN` and exited 0).
#[test]
fn a_spectrum_that_overflows_f64_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let list = dir.path().join("huge.csv");
    std::fs::write(
        &list,
        "wavelength_nm,relative_intensity\n500,1e308\n600,1e308\n",
    )
    .unwrap();
    let out = blueshift()
        .arg("spectrum")
        .arg("--line-list")
        .arg(&list)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("overflows f64"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}
