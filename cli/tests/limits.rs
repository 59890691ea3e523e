//! Resource limits (issue 23, items 1-5): the memory budget (`--max-memory`), the caps on
//! species, channels and `--threads`, inputs that are not regular files, line lists.
//! Every run is bounded by a generous wall-clock guard so a regression fails, not hangs.

mod common;

use std::path::Path;
use std::process::{Command, Output};

/// Guard for runs that must end promptly (a refusal takes milliseconds).
const PROMPT_S: u64 = 60;

fn blueshift(dir: &Path, args: &[&str]) -> Output {
    let (out, in_time) = common::output_within(
        Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .args(args)
            .current_dir(dir),
        PROMPT_S,
    );
    assert!(in_time, "blueshift {args:?} ran past {PROMPT_S} s");
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exit 1 with one line on stderr containing every one of `needles`.
fn refused(out: &Output, needles: &[&str]) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "missing {n:?} in: {err}");
    }
}

#[test]
fn synth_over_the_budget_is_refused_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    // 256^3 f32 = 67.1 MB > 32 MiB.
    let out = blueshift(
        dir.path(),
        &[
            "synth",
            "turbulence",
            "t.nrrd",
            "--res",
            "256",
            "--max-memory",
            "32M",
        ],
    );
    refused(
        &out,
        &["needs 67.1 MB", "memory budget is 33.6 MB", "--max-memory"],
    );
    assert!(!dir.path().join("t.nrrd").exists());
    // The same through the environment variable.
    let (out, _) = common::output_within(
        Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .args(["synth", "turbulence", "t.nrrd", "--res", "256"])
            .env("BLUESHIFT_MAX_MEMORY", "1M")
            .current_dir(dir.path()),
        PROMPT_S,
    );
    refused(&out, &["memory budget is 1.0 MB (--max-memory)"]);
    // Within the budget it runs.
    let ok = blueshift(
        dir.path(),
        &[
            "synth",
            "turbulence",
            "t.nrrd",
            "--res",
            "8",
            "--max-memory",
            "64M",
        ],
    );
    assert!(ok.status.success(), "{}", stderr(&ok));
}

#[test]
fn sizes_the_help_allows_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 2048^3 f32 = 34.4 GB: refused up front, not a SIGABRT (any machine: explicit budget).
    let out = blueshift(
        d,
        &[
            "synth",
            "turbulence",
            "t.nrrd",
            "--res",
            "2048",
            "--max-memory",
            "8G",
        ],
    );
    refused(&out, &["needs 34.4 GB", "--max-memory"]);
    let out = blueshift(
        d,
        &[
            "render",
            "--synth",
            "three-cubes",
            "--res",
            "2048",
            "--tf",
            "builtin:viridis",
            "--out",
            "r.exr",
            "--max-memory",
            "8G",
        ],
    );
    refused(&out, &["needs", "--max-memory"]);
    assert!(!d.join("r.exr").exists());
    let out = blueshift(
        d,
        &[
            "relativity",
            "--synth",
            "checker",
            "--width",
            "16384",
            "--height",
            "16384",
            "--out",
            "e.exr",
            "--max-memory",
            "1G",
        ],
    );
    refused(&out, &["16384x16384", "--max-memory"]);
    assert!(!d.join("e.exr").exists());
    // An 8192 x 8192 render is checked against the budget before rendering.
    let out = blueshift(
        d,
        &[
            "render",
            "--synth",
            "three-cubes",
            "--res",
            "8",
            "--tf",
            "builtin:viridis",
            "--width",
            "8192",
            "--height",
            "8192",
            "--out",
            "r.exr",
            "--max-memory",
            "1G",
        ],
    );
    refused(&out, &["8192x8192", "--max-memory"]);
    let out = blueshift(
        d,
        &["spectrum", "--blackbody", "5800", "--max-memory", "lots"],
    );
    refused(&out, &["--max-memory 'lots'"]);
}

#[test]
fn a_huge_exr_is_refused_from_its_header() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("big.exr");
    exr::prelude::write_rgb_file(&p, 2048, 2048, |_, _| (0.5f32, 0.5f32, 0.5f32)).unwrap();
    let out = blueshift(
        dir.path(),
        &[
            "tonemap",
            "big.exr",
            "--out",
            "o.png",
            "--max-memory",
            "32M",
        ],
    );
    refused(&out, &["2048x2048", "--max-memory"]);
    assert!(!dir.path().join("o.png").exists());
}

#[test]
fn threads_are_capped_at_four_per_core() {
    let dir = tempfile::tempdir().unwrap();
    let out = blueshift(
        dir.path(),
        &[
            "render",
            "--synth",
            "three-cubes",
            "--res",
            "8",
            "--tf",
            "builtin:viridis",
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            "r.exr",
            "--threads",
            "100000",
        ],
    );
    refused(&out, &["--threads 100000: at most", "per core"]);
    assert!(!dir.path().join("r.exr").exists());
}

fn mkfifo(p: &Path) {
    let ok = Command::new("mkfifo").arg(p).status().unwrap();
    assert!(ok.success());
}

#[test]
fn fifos_are_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A detached NRRD whose data file is a FIFO.
    mkfifo(&d.join("data.raw"));
    std::fs::write(
        d.join("v.nhdr"),
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nencoding: raw\nendian: little\ndata file: data.raw\n",
    )
    .unwrap();
    let out = blueshift(d, &["info", "v.nhdr"]);
    refused(&out, &["not a regular file", "FIFO"]);
    // The file named on the command line itself a FIFO, of each kind info sniffs.
    for name in ["f_8x8x8_uint8.raw", "f.nrrd", "f.fits"] {
        mkfifo(&d.join(name));
        let out = blueshift(d, &["info", name]);
        refused(&out, &["not a regular file", "FIFO"]);
    }
    // A render scene naming it, and a scene file that is itself a FIFO.
    std::fs::write(
        d.join("s.json"),
        r#"{"channels": [{"volume": "v.nhdr", "tf": "builtin:viridis"}]}"#,
    )
    .unwrap();
    let out = blueshift(d, &["render", "s.json", "--out", "r.exr"]);
    refused(&out, &["not a regular file"]);
    mkfifo(&d.join("fifo.json"));
    let out = blueshift(d, &["render", "fifo.json", "--out", "r.exr"]);
    refused(&out, &["not a regular file"]);
    // A Doppler scene whose field names a FIFO.
    std::fs::write(
        d.join("d.json"),
        r#"{"temperature": {"file": "v.nhdr", "unit": "K"},
            "species": [{"name": "H", "lines": "H", "density": {"value": 1, "unit": "cm-3"}}]}"#,
    )
    .unwrap();
    let out = blueshift(d, &["doppler", "--scene", "d.json", "--out", "d.exr"]);
    refused(&out, &["not a regular file"]);
    // A line list that is a FIFO.
    mkfifo(&d.join("lines.csv"));
    let out = blueshift(d, &["spectrum", "--line-list", "lines.csv"]);
    refused(&out, &["not a regular file"]);
}

#[test]
fn species_and_channels_have_a_stated_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ok = blueshift(d, &["synth", "turbulence", "n.nrrd", "--res", "8"]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let species: Vec<String> = (0..1000)
        .map(|i| {
            format!(
                r#"{{"name": "H{i}", "lines": "H", "density": {{"file": "n.nrrd", "unit": "cm-3"}}}}"#
            )
        })
        .collect();
    std::fs::write(
        d.join("d.json"),
        format!(
            r#"{{"temperature": {{"value": 8000, "unit": "K"}}, "species": [{}]}}"#,
            species.join(",")
        ),
    )
    .unwrap();
    let out = blueshift(d, &["doppler", "--scene", "d.json", "--out", "d.exr"]);
    refused(&out, &["1000 species", "MAX_SPECIES"]);
    let channels: Vec<&str> = (0..3000)
        .map(|_| r#"{"volume": "n.nrrd", "tf": "builtin:viridis"}"#)
        .collect();
    std::fs::write(
        d.join("s.json"),
        format!(r#"{{"channels": [{}]}}"#, channels.join(",")),
    )
    .unwrap();
    let out = blueshift(d, &["render", "s.json", "--out", "r.exr"]);
    refused(&out, &["3000 channels", "MAX_CHANNELS"]);
    // Two species sharing one file (read once) still render.
    std::fs::write(
        d.join("two.json"),
        r#"{"temperature": {"value": 8000, "unit": "K"}, "species": [
            {"name": "H", "lines": "H", "density": {"file": "n.nrrd", "unit": "cm-3"}},
            {"name": "He", "lines": "He", "density": {"file": "./n.nrrd", "unit": "cm-3"}}]}"#,
    )
    .unwrap();
    let out = blueshift(
        d,
        &[
            "doppler", "--scene", "two.json", "--width", "8", "--height", "8", "--out", "d.exr",
        ],
    );
    assert!(out.status.success(), "{}", stderr(&out));
}

#[test]
fn a_brick_larger_than_the_volume_is_capped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ok = blueshift(d, &["synth", "turbulence", "n.nrrd", "--res", "16"]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let out = blueshift(d, &["convert", "n.nrrd", "n.bsv", "--brick", "1024"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let len = std::fs::metadata(d.join("n.bsv")).unwrap().len();
    assert!(len < 1 << 20, "{len} bytes for a 16^3 volume");
}

#[test]
fn line_lists_need_their_header() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, text) in [
        ("none.csv", "500,1\n510,2\n"),
        ("other.csv", "lambda,intensity,upper_level\n500,1,3\n"),
    ] {
        std::fs::write(d.join(name), text).unwrap();
        let out = blueshift(d, &["spectrum", "--line-list", name]);
        refused(&out, &["wavelength_nm", "relative_intensity", name]);
    }
    // Swapped columns are read by name.
    std::fs::write(
        d.join("a.csv"),
        "wavelength_nm,relative_intensity\n656.3,1\n",
    )
    .unwrap();
    std::fs::write(
        d.join("b.csv"),
        "relative_intensity,wavelength_nm\n1,656.3\n",
    )
    .unwrap();
    let a = blueshift(d, &["spectrum", "--line-list", "a.csv", "--json"]);
    let b = blueshift(d, &["spectrum", "--line-list", "b.csv", "--json"]);
    assert!(a.status.success(), "{}", stderr(&a));
    assert_eq!(a.stdout, b.stdout);
}

#[test]
fn a_long_line_list_is_not_quadratic() {
    // 400,000 overlapping lines took 48 s when each line was inserted on its own; the sweep
    // takes about a second. The guard is generous; the speed is in the spectrum benches.
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from("wavelength_nm,relative_intensity\n");
    for i in 0..400_000u32 {
        let wl = 400.0 + f64::from(i) * 300.0 / 400_000.0;
        text.push_str(&format!("{wl},{}\n", 1 + i % 7));
    }
    std::fs::write(dir.path().join("many.csv"), text).unwrap();
    let out = blueshift(
        dir.path(),
        &["spectrum", "--line-list", "many.csv", "--json"],
    );
    assert!(out.status.success(), "{}", stderr(&out));
}

/// A `.bsv` whose one brick exceeds `--max-memory` is refused by `render` (the brick cache
/// holds at least one brick whatever `--cache-mb` says): 64^3 in bricks of 64 is one brick
/// of 66^3 floats, 1.15 MB.
#[test]
fn a_brick_larger_than_max_memory_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let vals: Vec<u8> = (0..64 * 64 * 64u32).map(|i| (i % 251) as u8).collect();
    std::fs::write(dir.path().join("v_64x64x64_uint8.raw"), &vals).unwrap();
    let ok = blueshift(
        dir.path(),
        &["convert", "v_64x64x64_uint8.raw", "v.bsv", "--brick", "64"],
    );
    assert!(ok.status.success(), "{}", stderr(&ok));
    let render = |budget: &str| {
        blueshift(
            dir.path(),
            &[
                "--max-memory",
                budget,
                "render",
                "--volume",
                "v.bsv",
                "--tf",
                "builtin:viridis",
                "--width",
                "8",
                "--height",
                "8",
                "--spp",
                "1",
                "--out",
                "o.exr",
            ],
        )
    };
    refused(
        &render("1M"),
        &["one brick of edge 64", "1.1 MB", "--max-memory", "--brick"],
    );
    assert!(!dir.path().join("o.exr").exists());
    let ok = render("64M");
    assert!(ok.status.success(), "{}", stderr(&ok));
}

/// A gzip NRRD with a reversed z axis cannot be streamed (a gzip stream does not run
/// backwards), so `convert` reads it whole; over `--max-memory` the refusal says so, where it
/// used to leave the user to wonder why a file that streams unreversed did not.
#[test]
fn a_reversed_gzip_nrrd_over_the_budget_says_why_it_is_read_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ok = |args: &[&str]| {
        let out = blueshift(d, args);
        assert!(out.status.success(), "{args:?}: {}", stderr(&out));
    };
    ok(&["synth", "turbulence", "t.nrrd", "--res", "64"]);
    ok(&["convert", "t.nrrd", "g.nhdr", "--gzip"]);
    assert!(d.join("g.raw.gz").exists());
    std::fs::write(
        d.join("r.nhdr"),
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 64 64 64\nspacings: 1 1 -1\n\
         encoding: gzip\nendian: little\ndata file: g.raw.gz\n",
    )
    .unwrap();
    let out = blueshift(d, &["convert", "r.nhdr", "o.bsv", "--max-memory", "512K"]);
    refused(&out, &["reversed z axis", "--max-memory"]);
    assert!(!d.join("o.bsv").exists());
}
