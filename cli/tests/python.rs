//! The Python package's tests (`python/tests`, pytest) against this test's `blueshift`
//! binary: the module's results are compared with the CLI's on the same inputs.
//! Without an importable `blueshift` module and pytest it prints `SKIP: ...` and passes,
//! unless `BLUESHIFT_REQUIRE_PYTHON_TESTS=1` (as CI sets, after installing the wheel).

use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_blueshift");

fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

#[test]
fn the_python_package_matches_the_cli() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let probe = Command::new(python())
        .args(["-c", "import blueshift._native, pytest, numpy"])
        .output();
    let importable = probe.as_ref().is_ok_and(|o| o.status.success());
    if !importable {
        let why = match &probe {
            Ok(o) => String::from_utf8_lossy(&o.stderr).trim().to_owned(),
            Err(e) => e.to_string(),
        };
        let required = std::env::var("BLUESHIFT_REQUIRE_PYTHON_TESTS").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "BLUESHIFT_REQUIRE_PYTHON_TESTS=1 but the module or pytest does not import: {why}"
        );
        println!(
            "SKIP: the Python tests need `pip install ./python pytest yt` ({})",
            why.lines().last().unwrap_or_default()
        );
        return;
    }
    let out = Command::new(python())
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "python/tests",
        ])
        .env("BLUESHIFT_CLI", BIN)
        .current_dir(&root)
        .output()
        .expect("cannot run pytest");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    if !stderr.trim().is_empty() {
        eprintln!("{stderr}");
    }
    assert!(
        out.status.success(),
        "pytest failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
}
