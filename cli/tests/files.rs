//! File safety (issue 23, items 5 and 6-11): a non-regular output is written into, never
//! replaced; an output that is an input (by path, hard link, symlink or a file a scene
//! names) or contradicts its Open SciVis name is refused; multi-file outputs are atomic as a
//! set; SIGINT/SIGTERM stop cleanly and remove temporary files; `blueshift clean` removes
//! only stale temporaries; outputs are 0644 under a 022 umask; usage errors are one line.

mod common;

use std::os::unix::fs::{FileTypeExt, MetadataExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_blueshift");

fn blueshift(args: &[&str], dir: &Path) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts a user error (exit 1) of one line containing `what`.
fn refused(o: &Output, what: &str) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    assert!(err.contains(what), "{err}");
}

/// A 8^3 float NRRD.
fn volume(dir: &Path, name: &str) {
    let o = blueshift(
        &[
            "synth",
            "three-cubes",
            name,
            "--res",
            "8",
            "--channel",
            "red",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

/// The `.blueshift-*` files in `dir`.
fn temps(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".blueshift-"))
        .collect()
}

fn mkfifo(p: &Path) {
    let s = Command::new("mkfifo").arg(p).status().unwrap();
    assert!(s.success());
}

/// Waits for `child` at most `secs` seconds (then kills it); its output.
fn wait_for(mut child: Child, secs: u64) -> Output {
    let end = Instant::now() + Duration::from_secs(secs);
    while Instant::now() < end {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    child.wait_with_output().unwrap()
}

/// Runs `args` writing into the FIFO `fifo` while `cat` reads it; returns what was read.
fn through_fifo(args: &[&str], dir: &Path, fifo: &Path) -> Vec<u8> {
    let cat = Command::new("cat")
        .arg(fifo)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let run = Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let o = wait_for(run, 60);
    assert!(o.status.success(), "{}", stderr(&o));
    let got = wait_for(cat, 5);
    assert!(
        std::fs::metadata(fifo).unwrap().file_type().is_fifo(),
        "the FIFO was replaced by a regular file"
    );
    got.stdout
}

#[test]
fn non_regular_output_is_written_into_never_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    volume(d, "v.nrrd");
    let fifo = d.join("pipe");
    mkfifo(&fifo);
    let csv = through_fifo(
        &["spectrum", "--blackbody", "5800", "--csv", "pipe"],
        d,
        &fifo,
    );
    assert!(
        String::from_utf8_lossy(&csv).starts_with("wavelength_nm,value\n"),
        "{}",
        String::from_utf8_lossy(&csv)
    );
    // `-` is standard output: no file named `-`.
    let o = blueshift(&["spectrum", "--blackbody", "5800", "--csv", "-"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("wavelength_nm,value\n"));
    assert!(!d.join("-").exists());
    // A path-based writer (EXR) too: the bytes reach the reader, the FIFO stays.
    let exr = through_fifo(
        &[
            "render",
            "--volume",
            "v.nrrd",
            "--tf",
            "builtin:grey",
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "--out",
            "pipe",
        ],
        d,
        &fifo,
    );
    assert_eq!(&exr[..4], &[0x76, 0x2f, 0x31, 0x01], "not an EXR");
    // A FIFO nobody reads: the writer waits, as a shell redirection would, and Ctrl-C still
    // stops it.
    let start = Instant::now();
    let o = interrupt(
        &["spectrum", "--blackbody", "5800", "--csv", "pipe"],
        d,
        "-INT",
        &|_| start.elapsed() > Duration::from_millis(800),
    );
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
    assert!(temps(d).is_empty(), "{:?}", temps(d));
}

#[test]
fn outputs_equal_to_inputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    volume(d, "v.nrrd");
    let before = std::fs::read(d.join("v.nrrd")).unwrap();
    std::fs::hard_link(d.join("v.nrrd"), d.join("hard.nrrd")).unwrap();
    std::os::unix::fs::symlink("v.nrrd", d.join("soft.nrrd")).unwrap();
    let render = |out: &str, extra: &[&str]| {
        let mut a = vec![
            "render",
            "--volume",
            "v.nrrd",
            "--tf",
            "builtin:grey",
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "--out",
            out,
        ];
        a.extend_from_slice(extra);
        blueshift(&a, d)
    };
    refused(&render("v.nrrd", &[]), "it is the input file");
    refused(&render("hard.nrrd", &[]), "it is the input file");
    refused(&render("soft.nrrd", &[]), "it is the input file");
    refused(&render("z.exr", &["--png", "./z.exr"]), "twice");
    // A file a scene names is an input too.
    std::fs::write(
        d.join("s.json"),
        r#"{ "channels": [ { "volume": "v.nrrd", "tf": "builtin:grey" } ] }"#,
    )
    .unwrap();
    refused(
        &blueshift(&["render", "s.json", "--out", "hard.nrrd"], d),
        "it is the input file",
    );
    refused(
        &blueshift(&["doppler", "--scene", "s.json", "--out", "s.json"], d),
        "it is the input file",
    );
    // tonemap, and convert with a detached header's data file.
    let o = render("img.exr", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::hard_link(d.join("img.exr"), d.join("img2.exr")).unwrap();
    refused(
        &blueshift(&["tonemap", "img.exr", "--out", "img2.exr"], d),
        "it is the input file",
    );
    let o = blueshift(&["convert", "v.nrrd", "det.nhdr"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    refused(
        &blueshift(&["convert", "det.nhdr", "det.raw"], d),
        "it is the input file",
    );
    // An Open SciVis name that contradicts the type written.
    refused(
        &blueshift(
            &[
                "convert",
                "v.nrrd",
                "v_8x8x8_int16.raw",
                "--type",
                "float32",
            ],
            d,
        ),
        "Open SciVis name says 8x8x8 int16",
    );
    assert!(!d.join("v_8x8x8_int16.raw").exists());
    // A big-endian name: the writer writes little-endian, which a reader of the name would
    // take byte-swapped.
    refused(
        &blueshift(
            &[
                "convert",
                "v.nrrd",
                "v_8x8x8_int16be.raw",
                "--type",
                "int16",
            ],
            d,
        ),
        "says big-endian",
    );
    assert!(!d.join("v_8x8x8_int16be.raw").exists());
    let o = blueshift(
        &["convert", "v.nrrd", "v_8x8x8_int16.raw", "--type", "int16"],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(d.join("v.nrrd")).unwrap(), before);
}

/// Detached NRRDs of two different 16^3 volumes of the same size (different seeds).
fn two_versions(d: &Path) {
    for (seed, name) in [("1", "a.nrrd"), ("2", "b.nrrd")] {
        let o = blueshift(
            &["synth", "turbulence", name, "--res", "16", "--seed", seed],
            d,
        );
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let o = blueshift(&["convert", "a.nrrd", "out.nhdr"], d);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Starts `convert b.nrrd out.nhdr` with a delay between its renames and waits until the
/// data file has been replaced (a new inode) while the header has not.
fn convert_until_data_renamed(d: &Path) -> Child {
    let (raw_ino, hdr_ino) = (
        std::fs::metadata(d.join("out.raw")).unwrap().ino(),
        std::fs::metadata(d.join("out.nhdr")).unwrap().ino(),
    );
    let child = Command::new(BIN)
        .args(["convert", "b.nrrd", "out.nhdr"])
        .current_dir(d)
        .env("BLUESHIFT_TEST_RENAME_DELAY_MS", "4000")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let end = Instant::now() + Duration::from_secs(30);
    while std::fs::metadata(d.join("out.raw")).unwrap().ino() == raw_ino {
        assert!(Instant::now() < end, "the data file was never renamed");
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(
        std::fs::metadata(d.join("out.nhdr")).unwrap().ino(),
        hdr_ino,
        "header renamed before its data file"
    );
    child
}

#[test]
fn killed_between_renames_the_reader_refuses_old_header_with_new_data() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_versions(d);
    let mut child = convert_until_data_renamed(d);
    child.kill().unwrap(); // SIGKILL: no clean-up runs.
    child.wait().unwrap();
    let o = blueshift(&["info", "out.nhdr"], d);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("does not match its header"),
        "{}",
        stderr(&o)
    );
    // The stale header temp is recognisable and `clean` removes it.
    let o = blueshift(&["clean"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(temps(d).is_empty(), "{:?}", temps(d));
}

#[test]
fn sigterm_between_renames_finishes_the_set() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_versions(d);
    let child = convert_until_data_renamed(d);
    let s = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(s.success());
    wait_for(child, 30);
    // The whole new set is in place: header and data agree and hold b.
    let o = blueshift(&["convert", "out.nhdr", "check.nrrd"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = blueshift(&["convert", "b.nrrd", "b2.nrrd"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(d.join("check.nrrd")).unwrap(),
        std::fs::read(d.join("b2.nrrd")).unwrap()
    );
    assert!(temps(d).is_empty(), "{:?}", temps(d));
}

/// Starts `args` in `dir` (plain progress lines every 0.3 s: stderr is a file) and sends
/// `signal` once `when(stderr so far)` holds; the output, stderr read from that file.
fn interrupt(args: &[&str], dir: &Path, signal: &str, when: &dyn Fn(&str) -> bool) -> Output {
    let log_dir = tempfile::tempdir().unwrap();
    let log = log_dir.path().join("stderr.txt");
    let child = Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .env("BLUESHIFT_PROGRESS_SECS", "0.3")
        .stderr(std::fs::File::create(&log).unwrap())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let end = Instant::now() + Duration::from_secs(60);
    while !when(&std::fs::read_to_string(&log).unwrap_or_default()) {
        assert!(Instant::now() < end, "never got going");
        std::thread::sleep(Duration::from_millis(20));
    }
    let s = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(s.success());
    let mut o = wait_for(child, 30);
    o.stderr = std::fs::read(&log).unwrap();
    o
}

#[test]
fn huge_spp_stops_on_sigint_and_frames_on_sigterm() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    volume(d, "v.nrrd");
    let mut args = vec![
        "render",
        "--volume",
        "v.nrrd",
        "--tf",
        "builtin:grey",
        "--width",
        "16",
        "--height",
        "16",
        "--out",
        "big.exr",
        "--png",
        "big.png",
    ];
    let o = interrupt(
        &[args.as_slice(), &["--spp", "100000000"]].concat(),
        d,
        "-INT",
        &|err| err.contains("render: "),
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert_eq!(
        err.trim_end().lines().last(),
        Some("blueshift: interrupted")
    );
    assert!(err.contains("render: "), "no progress shown: {err}");
    assert!(!d.join("big.exr").exists() && !d.join("big.png").exists());
    assert!(temps(d).is_empty(), "{:?}", temps(d));
    args.extend(["--spp", "1", "--warmup", "1000000", "--frames", "100000000"]);
    // Warm-up frames show progress too.
    let o = interrupt(&args, d, "-TERM", &|err| err.contains("render: "));
    assert_eq!(o.status.code(), Some(143), "{}", stderr(&o));
    assert!(stderr(&o).ends_with("blueshift: interrupted\n"));
    assert!(!d.join("big.exr").exists());
}

#[test]
fn sigint_removes_the_temporary_files_of_a_bsv_conversion() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = interrupt(
        &[
            "synth",
            "turbulence",
            "t.bsv",
            "--res",
            "192",
            "--brick",
            "16",
        ],
        d,
        "-INT",
        &|_| temps(d).iter().any(|n| n.ends_with(".bsv.partial")),
    );
    let err = stderr(&o);
    if o.status.success() {
        eprintln!("SKIP: the conversion finished before the signal: {err}");
        return;
    }
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(temps(d).is_empty(), "{:?}", temps(d));
    assert!(!d.join("t.bsv").exists());
}

#[test]
fn clean_removes_only_stale_blueshift_temporaries() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let me = std::process::id();
    let names = [
        ".blueshift-999999999-aB3dE.partial",        // dead pid: stale
        ".blueshift-999999998-x1.bsv.partial",       // dead pid: stale
        &format!(".blueshift-{me}-Zz9.partial.exr"), // running (this test): kept
        ".blueshift-999999997-notes.txt",            // not a temporary name: kept
        ".blueshift-check-abc",                      // old style, not ours to judge: kept
        "other.partial",                             // kept
    ];
    for n in &names {
        std::fs::write(d.join(n), b"x").unwrap();
    }
    std::fs::write(d.join("target.txt"), b"keep").unwrap();
    std::os::unix::fs::symlink("target.txt", d.join(".blueshift-999999996-ln.partial")).unwrap();
    let o = blueshift(&["clean", "--dry-run", "."], d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        stderr(&o)
            .lines()
            .filter(|l| l.starts_with("stale "))
            .count(),
        2
    );
    assert!(d.join(names[0]).exists());
    let o = blueshift(&["clean"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    let left: Vec<PathBuf> = names
        .iter()
        .map(|n| d.join(n))
        .filter(|p| p.exists())
        .collect();
    assert_eq!(left.len(), names.len() - 2, "{left:?}");
    assert!(!d.join(names[0]).exists() && !d.join(names[1]).exists());
    assert!(
        d.join(".blueshift-999999996-ln.partial")
            .symlink_metadata()
            .is_ok()
    );
    assert_eq!(std::fs::read(d.join("target.txt")).unwrap(), b"keep");
}

#[test]
fn every_output_is_0644_under_umask_022() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sh = |cmd: &str| {
        let o = Command::new("sh")
            .arg("-c")
            .arg(format!("umask 022 && {cmd}"))
            .env("B", BIN)
            .current_dir(d)
            .output()
            .unwrap();
        assert!(o.status.success(), "{cmd}: {}", stderr(&o));
    };
    sh("\"$B\" synth three-cubes v.nrrd --res 8 --channel red");
    sh(
        "\"$B\" render --volume v.nrrd --tf builtin:grey --width 8 --height 8 --spp 1 --out r.exr --png r.png",
    );
    sh("\"$B\" tonemap r.exr --op drago --out t.png");
    sh("\"$B\" tonemap r.exr --op reinhard --out t.hdr");
    sh("\"$B\" tonemap r.exr --op linear --out t.pfm");
    sh("\"$B\" tonemap r.exr --pseudocolor --out p.png");
    sh("\"$B\" convert v.nrrd d.nhdr");
    sh("\"$B\" convert v.nrrd d.bsv --brick 4");
    sh("\"$B\" spectrum --blackbody 5000 --csv s.csv");
    let img = common::read_exr(&d.join("r.exr"));
    assert_eq!(img.width(), 8);
    for n in [
        "v.nrrd", "r.exr", "r.png", "t.png", "t.hdr", "t.pfm", "p.png", "d.nhdr", "d.raw", "d.bsv",
        "s.csv",
    ] {
        let mode = std::fs::metadata(d.join(n)).unwrap().mode() & 0o777;
        assert_eq!(mode, 0o644, "{n}: {mode:o}");
    }
    assert!(temps(d).is_empty(), "{:?}", temps(d));
}

#[test]
fn usage_errors_are_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (args, want) in [
        (
            &["render", "--volume", "v.nrrd", "--widht", "8"][..],
            "similar argument exists: '--width'",
        ),
        (&["render", "--volume", "v.nrrd"][..], "--out"),
        (
            &["tonemap", "x.exr", "--op", "nope", "--out", "y.png"][..],
            "nope",
        ),
        (&["spectrum", "--blackbody", "abc"][..], "abc"),
        (&["nosuchverb"][..], "nosuchverb"),
    ] {
        let o = blueshift(args, d);
        let err = stderr(&o);
        refused(&o, want);
        assert!(err.starts_with("blueshift: "), "{err}");
        assert!(!err.contains("Usage:") && !err.contains("--help"), "{err}");
    }
    // Help still prints in full, with success.
    let o = blueshift(&["render", "--help"], d);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("Usage:"));
}
