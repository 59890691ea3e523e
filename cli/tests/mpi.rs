//! `--distributed` under `mpirun --oversubscribe` (the `mpi` feature): the data-parallel
//! marcher and Doppler with absorption against the single-process image, sample- and
//! tile-parallel tracking bit for bit, and a rank that cannot read its bricks stopping every
//! rank within seconds. Without `mpirun` (or without the feature) these tests skip with a
//! SKIP line, unless `BLUESHIFT_REQUIRE_MPI_TESTS=1` (CI), where that fails them.

use std::path::Path;
use std::process::{Command, Output};

mod common;

fn require() -> bool {
    std::env::var("BLUESHIFT_REQUIRE_MPI_TESTS").is_ok_and(|v| v == "1")
}

#[test]
fn mpi_tests_run_where_required() {
    if require() {
        if !cfg!(feature = "mpi") {
            panic!("BLUESHIFT_REQUIRE_MPI_TESTS=1 but the CLI was built without --features mpi");
        }
        assert!(
            mpirun().is_some(),
            "BLUESHIFT_REQUIRE_MPI_TESTS=1 but no mpirun"
        );
    }
}

/// `mpirun`, if there is one.
fn mpirun() -> Option<String> {
    let out = Command::new("mpirun").arg("--version").output().ok()?;
    out.status.success().then(|| "mpirun".to_owned())
}

/// Whether the MPI tests can run here: `false` (after a SKIP line) when not, failing
/// instead under [`require`].
fn can_run() -> bool {
    if !cfg!(feature = "mpi") {
        assert!(!require(), "built without the mpi feature");
        eprintln!("SKIP: the CLI was built without the mpi feature");
        return false;
    }
    if mpirun().is_none() {
        assert!(!require(), "no mpirun");
        eprintln!("SKIP: no mpirun");
        return false;
    }
    true
}

/// `mpirun --oversubscribe -np N blueshift ARGS` in `dir`, killed after `limit_s`.
fn mpi(n: usize, args: &[&str], dir: &Path, limit_s: u64) -> (Output, bool) {
    let mut cmd = Command::new("mpirun");
    cmd.args(["--oversubscribe", "-np", &n.to_string()])
        .arg(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        // Root in containers and CI; harmless otherwise.
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1");
    common::output_within(&mut cmd, limit_s)
}

fn single(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

fn ok(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn max_diff(a: &image::Rgba32FImage, b: &image::Rgba32FImage) -> f32 {
    assert_eq!(a.dimensions(), b.dimensions());
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

const RENDER: [&str; 12] = [
    "render",
    "--synth",
    "three-cubes",
    "--res",
    "20",
    "--tf",
    "builtin:viridis",
    "--width",
    "24",
    "--height",
    "20",
    "--device",
];

#[test]
fn distributed_tracking_matches_the_single_process_render() {
    if !can_run() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fn with<'a>(extra: &[&'a str]) -> Vec<&'a str> {
        let mut a: Vec<&str> = RENDER.to_vec();
        a.push("cpu");
        a.extend_from_slice(extra);
        a
    }
    // The marcher, data-parallel: within f32 rounding of the single process (a density where
    // no ray reaches the early-termination alpha, which a piece cannot know in front of it).
    let marcher = ["--method", "marcher", "--density-scale", "1", "--spp", "2"];
    let mut a = with(&marcher);
    a.extend(["--out", "one.exr"]);
    ok(&single(&a, d), "single marcher");
    let want = common::read_exr(&d.join("one.exr"));
    assert!(
        want.pixels().any(|p| p.0[3] > 0.3),
        "the marcher image shows something"
    );
    for n in [2, 3, 4] {
        let out = format!("data{n}.exr");
        let mut a = with(&marcher);
        a.extend(["--distributed", "data", "--out", &out]);
        let (o, in_time) = mpi(n, &a, d, 120);
        assert!(in_time, "mpirun -np {n} data hung");
        ok(&o, &format!("-np {n} data"));
        let got = common::read_exr(&d.join(&out));
        let diff = max_diff(&got, &want);
        assert!(diff <= 2e-5, "-np {n}: {diff}");
    }
    // Woodcock sample- and tile-parallel: bit for bit at the same seed.
    let mdwt = [
        "--method",
        "mdwt-1dda",
        "--density-scale",
        "4",
        "--spp",
        "5",
        "--seed",
        "9",
    ];
    let mut a = with(&mdwt);
    a.extend(["--out", "mc.exr"]);
    ok(&single(&a, d), "single mdwt");
    let want = common::read_exr(&d.join("mc.exr"));
    for (n, mode) in [(3, "samples"), (2, "tiles"), (4, "samples")] {
        let out = format!("{mode}{n}.exr");
        let mut a = with(&mdwt);
        a.extend(["--distributed", mode, "--out", &out]);
        let (o, in_time) = mpi(n, &a, d, 120);
        assert!(in_time, "mpirun -np {n} {mode} hung");
        ok(&o, &format!("-np {n} {mode}"));
        let got = common::read_exr(&d.join(&out));
        assert_eq!(got.as_raw(), want.as_raw(), "-np {n} {mode}");
    }
    // Woodcock data-parallel, rays forwarded between the pieces: bit for bit at the seed.
    let woodcock = [
        "--method",
        "woodcock",
        "--density-scale",
        "4",
        "--spp",
        "4",
        "--seed",
        "5",
    ];
    let mut a = with(&woodcock);
    a.extend(["--out", "wc.exr"]);
    ok(&single(&a, d), "single woodcock");
    let want = common::read_exr(&d.join("wc.exr"));
    for n in [2, 3] {
        let out = format!("wc{n}.exr");
        let mut a = with(&woodcock);
        a.extend(["--distributed", "data", "--out", &out]);
        let (o, in_time) = mpi(n, &a, d, 120);
        assert!(in_time, "mpirun -np {n} woodcock data hung");
        ok(&o, &format!("-np {n} woodcock data"));
        let got = common::read_exr(&d.join(&out));
        assert_eq!(got.as_raw(), want.as_raw(), "-np {n} woodcock data");
    }
    // Frame farming of a time series: three snapshots over 2 ranks, the single process's
    // frames byte for byte.
    for s in 1..=3 {
        let name = format!("t{s}.nrrd");
        let seed = s.to_string();
        let a = ["synth", "turbulence", &name, "--res", "12", "--seed", &seed];
        ok(&single(&a, d), "synth");
    }
    let series = [
        "render",
        "--tf",
        "builtin:inferno",
        "--tf-range",
        "0:1",
        "--method",
        "marcher",
        "--width",
        "16",
        "--height",
        "12",
        "--device",
        "cpu",
        "--series",
        "t1.nrrd",
        "t2.nrrd",
        "t3.nrrd",
    ];
    let mut a = series.to_vec();
    a.extend(["--out", "ts1.exr"]);
    ok(&single(&a, d), "single series");
    let mut a = series.to_vec();
    a.extend(["--out", "ts2.exr", "--distributed", "frames"]);
    let (o, in_time) = mpi(2, &a, d, 120);
    assert!(in_time, "series frames hung");
    ok(&o, "series frames");
    for k in 0..3 {
        assert_eq!(
            std::fs::read(d.join(format!("ts2_{k:04}.exr"))).unwrap(),
            std::fs::read(d.join(format!("ts1_{k:04}.exr"))).unwrap(),
            "series frame {k}"
        );
    }
}

#[test]
fn distributed_doppler_with_absorption_matches_the_single_process_image() {
    if !can_run() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = |out: &str| -> Vec<String> {
        [
            "doppler",
            "--synth",
            "galaxy",
            "--res",
            "20",
            "--species",
            "bb,H,C",
            "--velocity-factor",
            "30",
            "--absorption-factor",
            "5",
            "--merge-tol",
            "0",
            "--width",
            "16",
            "--height",
            "16",
            "--device",
            "cpu",
            "--exr-space",
            "xyz",
            "--out",
            out,
        ]
        .map(String::from)
        .to_vec()
    };
    let a = args("one.exr");
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    ok(&single(&a, d), "single doppler");
    let want = common::read_exr(&d.join("one.exr"));
    let peak = want.as_raw().iter().fold(0.0f32, |m, &v| m.max(v));
    assert!(peak > 0.0);
    for n in [2, 3] {
        let out = format!("d{n}.exr");
        let mut a = args(&out);
        a.extend(["--distributed".into(), "data".into()]);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let (o, in_time) = mpi(n, &a, d, 120);
        assert!(in_time, "mpirun -np {n} doppler hung");
        ok(&o, &format!("-np {n} doppler"));
        let got = common::read_exr(&d.join(&out));
        // Exact compositing, merge tolerance 0: equal up to rounding (stored as f32).
        let diff = max_diff(&got, &want);
        assert!(diff <= 1e-5 * peak, "-np {n}: {diff} (peak {peak})");
    }
    // The banded integrator with absorption: a depth per band; the samples on the pieces'
    // faces differ at second order in the step (1e-5 of the peak in dist/tests/engines.rs).
    let banded = |out: &str| {
        let mut a = args(out);
        a.extend(["--integrator", "banded:400"].map(String::from));
        a
    };
    let a = banded("b1.exr");
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    ok(&single(&a, d), "single banded doppler");
    let want = common::read_exr(&d.join("b1.exr"));
    let peak = want.as_raw().iter().fold(0.0f32, |m, &v| m.max(v));
    assert!(peak > 0.0);
    let mut a = banded("b3.exr");
    a.extend(["--distributed".into(), "data".into()]);
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    let (o, in_time) = mpi(3, &a, d, 120);
    assert!(in_time, "mpirun -np 3 banded doppler hung");
    ok(&o, "-np 3 banded doppler");
    let diff = max_diff(&common::read_exr(&d.join("b3.exr")), &want);
    assert!(diff <= 1e-4 * peak, "banded: {diff} (peak {peak})");
}

/// `doppler --distributed tiles` writes the single-process EXR byte for byte (absorbing
/// galaxy); `--cube` under `tiles` writes the single-process FITS byte for byte (absorbing
/// and emission-only), and under `data` a FITS whose values equal it within 1e-6 of the peak
/// for an emission-only scene (sums grouped by piece, then rounded to f32) and within 1e-3
/// for an absorbing one (the attenuation's chords).
#[test]
fn distributed_doppler_tiles_and_cubes_match_the_single_process_files() {
    if !can_run() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = |absorption: &str| -> Vec<String> {
        [
            "doppler",
            "--synth",
            "galaxy",
            "--res",
            "20",
            "--species",
            "bb,H,C",
            "--velocity-factor",
            "30",
            "--absorption-factor",
            absorption,
            "--width",
            "12",
            "--height",
            "10",
            "--device",
            "cpu",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |n: usize, args: Vec<String>, what: &str| {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        if n == 1 {
            ok(&single(&a, d), what);
        } else {
            let (o, in_time) = mpi(n, &a, d, 120);
            assert!(in_time, "{what} hung");
            ok(&o, what);
        }
    };
    // The image, tiles.
    let mut a = base("5");
    a.extend(["--out".into(), "one.exr".into()]);
    run(1, a, "single image");
    let mut a = base("5");
    a.extend([
        "--out".into(),
        "t3.exr".into(),
        "--distributed".into(),
        "tiles".into(),
    ]);
    run(3, a, "tiles image");
    assert_eq!(
        std::fs::read(d.join("t3.exr")).unwrap(),
        std::fs::read(d.join("one.exr")).unwrap()
    );
    // Cubes.
    let cube = |absorption: &str, out: &str, mode: Option<&str>| -> Vec<String> {
        let mut a = base(absorption);
        a.extend(
            [
                "--cube",
                out,
                "--line",
                "Halpha",
                "--velocity-bins",
                "-600:600:16",
                "--axis",
                "z",
            ]
            .map(String::from),
        );
        if let Some(m) = mode {
            a.extend(["--distributed".into(), m.into()]);
        }
        a
    };
    let values = |p: &str| -> Vec<f32> {
        let b = std::fs::read(d.join(p)).unwrap();
        let n = 12 * 10 * 16;
        let data = &b[b.len() - n * 4 - (2880 - (n * 4) % 2880) % 2880..][..n * 4];
        data.chunks_exact(4)
            .map(|c| f32::from_be_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    for absorption in ["0", "5"] {
        let one = format!("one_{absorption}.fits");
        run(1, cube(absorption, &one, None), "single cube");
        let t = format!("t_{absorption}.fits");
        run(2, cube(absorption, &t, Some("tiles")), "tiles cube");
        assert_eq!(
            std::fs::read(d.join(&t)).unwrap(),
            std::fs::read(d.join(&one)).unwrap(),
            "absorption {absorption}"
        );
    }
    // Frame farming of a camera path: `--orbit 5` over 2 ranks writes the single process's
    // five frames byte for byte.
    let mut a = base("5");
    a.extend(["--orbit", "5", "--out", "orbit1.exr"].map(String::from));
    run(1, a, "single orbit");
    let mut a = base("5");
    a.extend(
        [
            "--orbit",
            "5",
            "--out",
            "orbit2.exr",
            "--distributed",
            "frames",
        ]
        .map(String::from),
    );
    run(2, a, "frames orbit");
    for k in 0..5 {
        assert_eq!(
            std::fs::read(d.join(format!("orbit2_{k:04}.exr"))).unwrap(),
            std::fs::read(d.join(format!("orbit1_{k:04}.exr"))).unwrap(),
            "orbit frame {k}"
        );
    }
    run(3, cube("0", "data.fits", Some("data")), "data cube");
    let (got, want) = (values("data.fits"), values("one_0.fits"));
    let peak = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(peak > 0.0);
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 1e-6 * peak, "{worst} of {peak}");
    // An absorbing cube under `data`: each piece's rays marched behind the depth in front
    // of it (merges off on both sides): the single process's cube up to the order of the
    // f64 sums (bit for bit in dist/tests/engines.rs).
    let merges_off = |mut a: Vec<String>| {
        a.extend(["--merge-tol", "0"].map(String::from));
        a
    };
    run(
        1,
        merges_off(cube("5", "one_5m.fits", None)),
        "single absorbing cube",
    );
    run(
        3,
        merges_off(cube("5", "data5.fits", Some("data"))),
        "data absorbing cube",
    );
    let (got, want) = (values("data5.fits"), values("one_5m.fits"));
    let peak = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(peak > 0.0);
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 1e-6 * peak, "absorbing: {worst} of {peak}");
}

#[test]
fn a_rank_that_cannot_read_its_bricks_stops_every_rank() {
    if !can_run() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(
        &single(
            &[
                "synth",
                "marschner-lobb",
                "m.bsv",
                "--res",
                "32",
                "--brick",
                "8",
            ],
            d,
        ),
        "synth",
    );
    // Level 0 holds 4x4x4 bricks of 10^3 f32 (edge 8, apron 1) from byte 4096, x fastest.
    // Two ranks split x at voxel 16: brick (3, 0, 0) is read by rank 1 only. Damage it (its
    // checksum then fails on read).
    let p = d.join("m.bsv");
    let mut bytes = std::fs::read(&p).unwrap();
    let at = 4096 + 3 * 4000 + 2000;
    for b in &mut bytes[at..at + 64] {
        *b ^= 0x5a;
    }
    std::fs::write(&p, bytes).unwrap();
    let start = std::time::Instant::now();
    let (o, in_time) = mpi(
        2,
        &[
            "render",
            "--volume",
            "m.bsv",
            "--tf",
            "builtin:viridis",
            "--method",
            "marcher",
            "--width",
            "16",
            "--height",
            "16",
            "--device",
            "cpu",
            "--distributed",
            "data",
            "--out",
            "bad.exr",
        ],
        d,
        60,
    );
    let secs = start.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(in_time, "the job hung: {err}");
    assert!(!o.status.success(), "{err}");
    assert!(secs < 30.0, "{secs} s");
    // One message, from the rank that failed, naming the brick's problem.
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("blueshift:"))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("rank 1"), "{err}");
    assert!(!d.join("bad.exr").exists());
}

#[test]
fn distributed_is_refused_without_the_mpi_build_or_for_a_wrong_mode() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = single(
        &[
            "doppler",
            "--synth",
            "galaxy",
            "--res",
            "8",
            "--width",
            "4",
            "--height",
            "4",
            "--distributed",
            "samples",
            "--out",
            "x.exr",
        ],
        d,
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("`doppler` distributes data, tiles, frames"),
        "{err}"
    );
    if !cfg!(feature = "mpi") {
        let mut a: Vec<&str> = RENDER.to_vec();
        a.extend(["cpu", "--distributed", "samples", "--out", "y.exr"]);
        let o = single(&a, d);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--features mpi"), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}

/// The Enzo snapshot copied into `d` (grid 9's data pointed at a missing file when `break9`)
/// with an emission-only AMR scene file beside it, subtracting the mean velocity (a pass
/// over the whole velocity, which every rank then reads) when `mean`.
fn enzo_scene(d: &Path, break9: bool, mean: bool) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let src = root.join("../shared/data/enzo-moving7/original");
    let snap = d.join("enzo");
    std::fs::create_dir_all(&snap).unwrap();
    for e in std::fs::read_dir(&src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), snap.join(e.file_name())).unwrap();
    }
    if break9 {
        let h = snap.join("moving7_0010.hierarchy");
        let text = std::fs::read_to_string(&h).unwrap();
        let at = text.find("Grid = 9").unwrap();
        let (head, tail) = text.split_at(at);
        let tail = tail.replacen("moving7_0010.cpu0000", "moving7_0010.cpu0009", 1);
        std::fs::write(&h, format!("{head}{tail}")).unwrap();
    }
    let scene = std::fs::read_to_string(root.join("scenes/enzo-moving7-amr.json")).unwrap();
    let scene = scene
        .replace("\"../../shared/data/enzo-moving7/original\"", "\"enzo\"")
        .replace(
            "\"subtract_mean\": true",
            &format!("\"subtract_mean\": {mean}"),
        );
    let p = d.join(format!("amr_{break9}_{mean}.json"));
    std::fs::write(&p, scene).unwrap();
    p
}

/// Rank 0's `AMR blocks read per rank (of N): B0 B1 ...` line: (reads, N).
fn amr_reads(stderr: &[u8]) -> (Vec<usize>, usize) {
    let err = String::from_utf8_lossy(stderr);
    let line = err
        .lines()
        .find_map(|l| l.strip_prefix("AMR blocks read per rank (of "))
        .unwrap_or_else(|| panic!("no AMR reads line: {err}"));
    let (total, reads) = line.split_once("): ").unwrap();
    (
        reads
            .split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect(),
        total.parse().unwrap(),
    )
}

#[test]
fn data_parallel_amr_reads_only_each_ranks_blocks() {
    if !can_run() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (n, mean) in [(2, false), (4, false), (3, true)] {
        let scene = enzo_scene(d, false, mean);
        let scene = scene.to_str().unwrap();
        let args = |out: &str| {
            [
                "doppler",
                "--scene",
                scene,
                "--width",
                "24",
                "--height",
                "20",
                "--exr-space",
                "xyz",
                "--device",
                "cpu",
                "--out",
                out,
            ]
            .map(String::from)
            .to_vec()
        };
        let one = format!("one_{mean}.exr");
        let a = args(&one);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        ok(&single(&a, d), "single AMR");
        let want = common::read_exr(&d.join(&one));
        let peak = want.as_raw().iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(peak > 0.0);
        let out = format!("data{n}_{mean}.exr");
        let mut a = args(&out);
        a.extend(["--distributed", "data"].map(String::from));
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let (o, in_time) = mpi(n, &a, d, 300);
        assert!(in_time, "-np {n} AMR data hung");
        ok(&o, &format!("-np {n} AMR data"));
        // Emission only: additive XYZ, equal up to f32 rounding of the sums.
        let got = common::read_exr(&d.join(&out));
        let diff = max_diff(&got, &want);
        assert!(diff <= 1e-5 * peak, "-np {n}: {diff} of {peak}");
        // Every rank reports its reads; the ranks away from the collapsing clump (grids 6 to
        // 10 around (0.75, 0.75, 0.75)) read fewer blocks than the hierarchy holds (with the
        // mean velocity subtracted, every rank reads the velocity's 30 whole).
        let (reads, total) = amr_reads(&o.stderr);
        assert_eq!(reads.len(), n);
        assert!(total > 0 && reads.iter().all(|&r| r <= total));
        if mean {
            assert!(reads.iter().all(|&r| r >= 30), "{reads:?}");
        }
        assert!(
            reads.iter().any(|&r| r < total),
            "-np {n}: every rank read every block: {reads:?} of {total}"
        );
    }
    // A rank that cannot read a block it needs (grid 9's file is missing) stops every rank
    // with one message naming the file; the ranks that do not need it say nothing.
    let broken = enzo_scene(d, true, false);
    let broken = broken.to_str().unwrap();
    let a = [
        "doppler",
        "--scene",
        broken,
        "--width",
        "24",
        "--height",
        "20",
        "--device",
        "cpu",
        "--out",
        "broken.exr",
        "--distributed",
        "data",
    ];
    let (o, in_time) = mpi(2, &a, d, 120);
    assert!(in_time, "a missing AMR grid file hung the job");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.matches("moving7_0010.cpu0009").count(), 1, "{err}");
    assert_eq!(err.matches("blueshift:").count(), 1, "{err}");
    assert!(!d.join("broken.exr").exists());
}
