//! What every verb tells the user (issue 19, items 6-10): a transfer function whose domain
//! misses the data is warned about and `--tf-range` stretches it; outputs are checked before
//! any work; one `wrote PATH` line per output; plain progress lines off a terminal; the
//! marcher at 1 spp without "noise inf"; `--exposure` in stops everywhere; a linear tone map
//! that is not black; output modes follow the umask; no XDG_RUNTIME_DIR noise.

use std::path::Path;
use std::process::{Command, Output};

fn blueshift(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "{}", stderr(o));
    stderr(o)
}

/// A 9^3 NRRD whose values run 0 ..= 3926 (a CT-like range), unit spacing.
fn write_ct(dir: &Path) {
    let mut bytes = b"NRRD0004\ntype: float\ndimension: 3\nsizes: 9 9 9\nspacings: 1 1 1\nendian: little\nencoding: raw\n\n".to_vec();
    for i in 0..729u32 {
        bytes.extend_from_slice(&(3926.0 * i as f32 / 728.0).to_le_bytes());
    }
    std::fs::write(dir.join("ct.nrrd"), bytes).unwrap();
    // A ParaView preset on [0, 1]: opacity ramps from 0 to 1.
    std::fs::write(
        dir.join("preset.json"),
        r#"[ { "Name": "ramp", "ColorSpace": "RGB",
               "RGBPoints": [0, 0, 0, 0, 1, 1, 1, 1],
               "Points": [0, 0, 0.5, 0, 1, 1, 0.5, 0] } ]"#,
    )
    .unwrap();
}

fn mean_alpha(p: &Path) -> f64 {
    let img = image::open(p).unwrap().to_rgba32f();
    img.pixels().map(|p| f64::from(p.0[3])).sum::<f64>() / f64::from(img.width() * img.height())
}

/// A render of `ct.nrrd`, thin enough (density scale 0.05) that opacity shows in alpha.
const CT: [&str; 11] = [
    "render",
    "--volume",
    "ct.nrrd",
    "--camera",
    "ortho",
    "--width",
    "12",
    "--height",
    "12",
    "--density-scale",
    "0.05",
];

fn ct_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut v: Vec<&str> = CT.to_vec();
    v.extend(["--spp", "2", "--method", "marcher"]);
    v.extend_from_slice(extra);
    v
}

#[test]
fn a_tf_domain_that_misses_the_data_is_warned_about_and_tf_range_stretches_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_ct(d);
    // The preset on [0, 1] over 0-3926: every voxel above 1 is fully opaque.
    let err = ok(&blueshift(
        &ct_args(&["--tf", "preset.json", "--out", "a.exr"]),
        d,
    ));
    assert!(err.contains("warning: channel 0"), "{err}");
    assert!(
        err.contains("[0, 1]") && err.contains("[0, 3926]"),
        "names both ranges: {err}"
    );
    assert!(err.contains("--tf-range data"), "{err}");
    let silhouette = mean_alpha(&d.join("a.exr"));
    // --tf-range data: the ramp spans the data, no warning, a translucent volume.
    let err = ok(&blueshift(
        &ct_args(&[
            "--tf",
            "preset.json",
            "--tf-range",
            "data",
            "--out",
            "b.exr",
        ]),
        d,
    ));
    assert!(!err.contains("warning"), "{err}");
    let stretched = mean_alpha(&d.join("b.exr"));
    assert!(
        stretched < 0.9 * silhouette,
        "stretched {stretched} vs silhouette {silhouette}"
    );
    // LO:HI stretches over that interval: [0, 7852] puts all data in the lower half.
    ok(&blueshift(
        &ct_args(&[
            "--tf",
            "preset.json",
            "--tf-range",
            "0:7852",
            "--out",
            "c.exr",
        ]),
        d,
    ));
    let half = mean_alpha(&d.join("c.exr"));
    assert!(half < stretched, "{half} vs {stretched}");
    // Built-in maps already span the data: no warning.
    let err = ok(&blueshift(
        &ct_args(&["--tf", "builtin:grey", "--out", "d.exr"]),
        d,
    ));
    assert!(!err.contains("warning"), "{err}");
    // A bad range is refused with the flag's name, before anything is written.
    let o = blueshift(
        &ct_args(&["--tf", "preset.json", "--tf-range", "5:1", "--out", "e.exr"]),
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--tf-range"), "{}", stderr(&o));
    assert!(!d.join("e.exr").exists());
    // The help says the built-in maps are already stretched.
    let help = blueshift(&["render", "--help"], d);
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(text.contains("--tf-range") && text.contains("already stretched"));
}

#[test]
fn outputs_are_checked_before_any_input_is_read_or_work_is_done() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_ct(d);
    std::fs::create_dir(d.join("folder")).unwrap();
    // The volume does not exist either: the output's error comes first, so nothing was
    // loaded (let alone rendered).
    for (out, why) in [
        ("missing/o.exr", "does not exist"),
        ("folder", "is a folder"),
    ] {
        let o = blueshift(
            &[
                "render",
                "--volume",
                "nope.nrrd",
                "--tf",
                "builtin:grey",
                "--out",
                out,
            ],
            d,
        );
        assert_eq!(o.status.code(), Some(1), "{out}");
        let err = stderr(&o);
        assert!(err.contains(why) && err.contains(out), "{out}: {err}");
        assert!(!err.contains("nope.nrrd"), "{out}: {err}");
        assert_eq!(err.lines().count(), 1, "one line: {err}");
    }
    // The PNG preview's folder is checked as well, before the render.
    let o = blueshift(
        &ct_args(&[
            "--tf",
            "builtin:grey",
            "--out",
            "ok.exr",
            "--png",
            "gone/p.png",
        ]),
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("gone"), "{}", stderr(&o));
    assert!(!d.join("ok.exr").exists(), "no render ran");
    // An output that is the input is refused (convert would overwrite its own input).
    let before = std::fs::read(d.join("ct.nrrd")).unwrap();
    let o = blueshift(&["convert", "ct.nrrd", "ct.nrrd"], d);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("input file"), "{}", stderr(&o));
    assert_eq!(std::fs::read(d.join("ct.nrrd")).unwrap(), before);
    // Every verb refuses a missing folder at once.
    for args in [
        vec!["synth", "three-cubes", "missing/v.nrrd", "--res", "8"],
        vec!["convert", "ct.nrrd", "missing/v.nrrd"],
        vec!["tonemap", "nope.exr", "--out", "missing/t.png"],
        vec!["doppler", "--res", "8", "--out", "missing/d.exr"],
        vec![
            "relativity",
            "--synth",
            "checker",
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            "missing/r.png",
        ],
        vec!["spectrum", "--blackbody", "5800", "--plot", "missing/s.png"],
        vec![
            "tf",
            "lut",
            "builtin:grey",
            "--entries",
            "8",
            "--out",
            "missing/l.exr",
        ],
        vec![
            "tf",
            "import-paraview",
            "preset.json",
            "--out",
            "missing/t.json",
        ],
    ] {
        let o = blueshift(&args, d);
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        assert!(
            stderr(&o).contains("does not exist"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
}

/// The paths of the `wrote PATH` lines (the detail in parentheses dropped).
fn wrote(err: &str) -> Vec<String> {
    err.lines()
        .filter_map(|l| l.strip_prefix("wrote "))
        .map(|l| l.split(" (").next().unwrap_or(l).to_owned())
        .collect()
}

#[test]
fn every_verb_prints_one_wrote_line_per_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_ct(d);
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            ct_args(&["--tf", "builtin:grey", "--out", "r.exr", "--png", "r.png"]),
            vec!["r.exr", "r.png"],
        ),
        (
            vec![
                "relativity",
                "--synth",
                "checker",
                "--width",
                "16",
                "--height",
                "8",
                "--out",
                "rel.exr",
                "--png",
                "rel.png",
            ],
            vec!["rel.exr", "rel.png"],
        ),
        (
            vec!["tf", "import-paraview", "preset.json", "--out", "imp.json"],
            vec!["imp.json"],
        ),
        (
            vec!["tf", "export-paraview", "builtin:grey", "--out", "exp.json"],
            vec!["exp.json"],
        ),
        (
            vec![
                "spectrum",
                "--blackbody",
                "5800",
                "--plot",
                "s.png",
                "--csv",
                "s.csv",
            ],
            vec!["s.csv", "s.png"],
        ),
        (vec!["tonemap", "rel.exr", "--out", "t.png"], vec!["t.png"]),
        // A detached header and its data file are two outputs.
        (
            vec!["convert", "ct.nrrd", "c.nhdr"],
            vec!["c.raw", "c.nhdr"],
        ),
        (
            vec![
                "doppler", "--res", "8", "--width", "8", "--height", "8", "--out", "dop.exr",
            ],
            vec!["dop.exr", "dop.png"],
        ),
    ];
    for (args, outs) in cases {
        let err = ok(&blueshift(&args, d));
        assert_eq!(wrote(&err), outs, "{args:?}: {err}");
        for o in outs {
            assert!(d.join(o).is_file(), "{o}");
        }
    }
}

#[test]
fn progress_is_reported_in_plain_lines_when_stderr_is_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // stderr is a pipe here; an interval of 0 prints every update instead of one every 5 s.
    let run = |args: &[&str], secs: &str| {
        Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .args(args)
            .current_dir(d)
            .env("BLUESHIFT_PROGRESS_SECS", secs)
            .output()
            .unwrap()
    };
    let render = [
        "render",
        "--synth",
        "three-cubes",
        "--res",
        "8",
        "--tf",
        "builtin:grey",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "4",
        "--out",
        "p.exr",
    ];
    let err = ok(&run(&render, "0"));
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("render: ")).collect();
    // One line per sweep of passes (passes run in sweeps when nothing needs each one):
    // counts rising to the last pass, which reports the noise.
    let counts: Vec<u32> = lines
        .iter()
        .map(|l| {
            l["render: ".len()..]
                .split('/')
                .next()
                .unwrap()
                .parse()
                .unwrap()
        })
        .collect();
    assert!(
        !counts.is_empty() && counts.windows(2).all(|w| w[0] < w[1]),
        "{err}"
    );
    let last = lines.last().unwrap();
    assert!(last.starts_with("render: 4/4 passes (100 %)"), "{err}");
    assert!(last.contains("noise"), "{err}");
    // The default interval prints nothing for a job shorter than it.
    let err = ok(&run(&render, "600"));
    assert!(!err.contains("render: "), "{err}");
    let err = ok(&run(
        &[
            "doppler", "--res", "8", "--width", "8", "--height", "6", "--out", "d.exr",
        ],
        "0",
    ));
    assert!(err.contains("doppler: 6/6 rows (100 %)"), "{err}");
}

#[test]
fn the_marcher_renders_one_sample_per_pixel_and_prints_no_infinite_noise() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_ct(d);
    let mut args: Vec<&str> = CT.to_vec();
    args.extend([
        "--method",
        "marcher",
        "--tf",
        "builtin:grey",
        "--out",
        "m.exr",
    ]);
    let err = ok(&blueshift(&args, d));
    assert!(err.contains("wrote m.exr (1 spp, "), "{err}");
    assert!(!err.contains("inf"), "{err}");
    args.push("--json");
    let o = blueshift(&args, d);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["spp"], 1);
    assert!(v["noise"].is_null());
}

#[test]
fn exposure_is_in_stops_in_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let doppler = |extra: &[&str], out: &str| {
        let mut a = vec!["doppler", "--res", "8", "--width", "12", "--height", "12"];
        a.extend_from_slice(extra);
        a.extend(["--out", out]);
        ok(&blueshift(&a, d));
        std::fs::read(d.join(out).with_extension("png")).unwrap()
    };
    // Doppler: a fixed scale of 0.25 plus 2 stops is a fixed scale of 1; the percentile
    // scaling plus 1 stop is brighter than without.
    let one = doppler(&["--exposure-scale", "1"], "a.exr");
    let quarter_up2 = doppler(&["--exposure-scale", "0.25", "--exposure", "2"], "b.exr");
    assert_eq!(one, quarter_up2);
    let sum = |p: &[u8]| {
        let img = image::load_from_memory(p).unwrap().to_rgb8();
        img.pixels()
            .map(|p| p.0.iter().map(|&c| u64::from(c)).sum::<u64>())
            .sum::<u64>()
    };
    let p99 = doppler(&[], "c.exr");
    let p99_up = doppler(&["--exposure", "1"], "e.exr");
    assert!(sum(&p99_up) > sum(&p99));
    // The old percentile spelling on --exposure points to --exposure-scale.
    let o = blueshift(
        &[
            "doppler",
            "--res",
            "8",
            "--exposure",
            "p50",
            "--out",
            "f.exr",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--exposure-scale p50"),
        "{}",
        stderr(&o)
    );
    // Tonemap and render count stops the same way: +1 stop doubles the linear display.
    let hdr = d.join("in.pfm");
    write_pfm(&hdr, 8, 4, |x, _| 0.01 * (1.0 + x as f32));
    let lin = |stops: &str, out: &str| {
        ok(&blueshift(
            &[
                "tonemap",
                "in.pfm",
                "--op",
                "linear",
                "--white",
                "1",
                "--exposure",
                stops,
                "--out",
                out,
            ],
            d,
        ));
        read_pfm_first(&d.join(out))
    };
    let (a, b) = (lin("0", "l0.pfm"), lin("1", "l1.pfm"));
    assert!((b / a - 2.0).abs() < 1e-4, "{a} {b}");
}

fn write_pfm(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> f32) {
    let mut bytes = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for y in (0..h).rev() {
        for x in 0..w {
            let v = f(x, y);
            for _ in 0..3 {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

/// The first float of a little-endian PFM's data (its bottom-left pixel's red).
fn read_pfm_first(path: &Path) -> f32 {
    let bytes = std::fs::read(path).unwrap();
    let mut newlines = 0;
    let start = bytes
        .iter()
        .position(|&b| {
            newlines += usize::from(b == b'\n');
            newlines == 3
        })
        .unwrap()
        + 1;
    f32::from_le_bytes(bytes[start..start + 4].try_into().unwrap())
}

#[test]
fn linear_tone_mapping_of_an_image_with_a_hot_pixel_is_not_black() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A grey 0.5 image with one pixel at 1e4 (a firefly, a star): mapping the maximum to 1
    // left everything else at 5e-5 of the display, black in 8 bits.
    write_pfm(&d.join("hot.pfm"), 32, 32, |x, y| {
        if (x, y) == (3, 5) { 1e4 } else { 0.5 }
    });
    ok(&blueshift(
        &["tonemap", "hot.pfm", "--op", "linear", "--out", "hot.png"],
        d,
    ));
    let img = image::open(d.join("hot.png")).unwrap().to_rgb8();
    let grey = img.get_pixel(10, 10).0;
    assert!(grey.iter().all(|&c| c > 200), "{grey:?}");
    // --white still sets the luminance that maps to 1.
    ok(&blueshift(
        &[
            "tonemap", "hot.pfm", "--op", "linear", "--white", "1e4", "--out", "max.png",
        ],
        d,
    ));
    let img = image::open(d.join("max.png")).unwrap().to_rgb8();
    assert!(img.get_pixel(10, 10).0.iter().all(|&c| c < 5));
}

#[cfg(unix)]
#[test]
fn outputs_get_0666_less_the_umask() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_ct(d);
    let bin = env!("CARGO_BIN_EXE_blueshift");
    for (umask, mode) in [("022", 0o644), ("027", 0o640)] {
        let sub = d.join(umask);
        std::fs::create_dir(&sub).unwrap();
        let script = format!(
            "umask {umask} && \
             {bin} render --volume ../ct.nrrd --tf builtin:grey --width 8 --height 8 --spp 1 \
               --method marcher --out r.exr --png r.png --tonemap drago && \
             {bin} tonemap r.exr --out t.png && \
             {bin} tf lut builtin:grey --entries 4 --out l.exr && \
             {bin} synth three-cubes v.nrrd --res 4"
        );
        let o = Command::new("sh")
            .arg("-c")
            .arg(&script)
            .current_dir(&sub)
            .output()
            .unwrap();
        ok(&o);
        for f in ["r.exr", "r.png", "t.png", "l.exr", "v.nrrd"] {
            let m = std::fs::metadata(sub.join(f)).unwrap().permissions().mode() & 0o777;
            assert_eq!(m, mode, "{f} under umask {umask}: {m:o}");
        }
    }
}

#[test]
fn the_vulkan_loader_says_nothing_about_xdg_runtime_dir() {
    let dir = tempfile::tempdir().unwrap();
    // gpu-info creates a wgpu instance; without XDG_RUNTIME_DIR the loader used to print
    // "error: XDG_RUNTIME_DIR is invalid or not set in the environment." twice.
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("gpu-info")
        .env_remove("XDG_RUNTIME_DIR")
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

/// A closed stderr (`2>&1 | head -1` after its line) does not turn a finished job into a
/// panic (exit 101): messages are best effort, the exit code says the outcome.
#[test]
fn a_closed_stderr_is_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["synth", "marschner-lobb", "--res", "8", "m.nrrd"])
        .current_dir(dir.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0));
    assert!(dir.path().join("m.nrrd").is_file());
}
