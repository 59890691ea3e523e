//! `blueshift view` in a real browser: runs `view/tests/browser/e2e.mjs` (headless Debian
//! Chromium driven by playwright-core, against the real server) with this test's binary.
//! Without `/usr/bin/chromium` or `view/tests/browser/node_modules/playwright-core` it
//! prints `SKIP: ...` and passes, unless `BLUESHIFT_REQUIRE_BROWSER_TESTS=1` (as CI sets).

use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_blueshift");
const CHROMIUM: &str = "/usr/bin/chromium";

fn required() -> bool {
    std::env::var("BLUESHIFT_REQUIRE_BROWSER_TESTS").is_ok_and(|v| v == "1")
}

#[test]
fn the_page_works_end_to_end_in_headless_chromium() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir = root.join("view/tests/browser");
    let mut missing = Vec::new();
    if !Path::new(CHROMIUM).exists() {
        missing.push(format!("{CHROMIUM} (apt-get install chromium)"));
    }
    if !dir.join("node_modules/playwright-core").is_dir() {
        missing.push(format!(
            "{} (npm ci in {})",
            dir.join("node_modules/playwright-core").display(),
            dir.display()
        ));
    }
    let node = Command::new("node").arg("--version").output();
    if !node.as_ref().is_ok_and(|o| o.status.success()) {
        missing.push("node".to_owned());
    }
    if !missing.is_empty() {
        let why = format!("the browser tests need {}", missing.join(" and "));
        assert!(!required(), "BLUESHIFT_REQUIRE_BROWSER_TESTS=1 but {why}");
        println!("SKIP: {why}");
        return;
    }
    let out = Command::new("node")
        .arg(dir.join("e2e.mjs"))
        .arg(BIN)
        .current_dir(&root)
        .output()
        .expect("cannot run node");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    if !stderr.trim().is_empty() {
        eprintln!("{stderr}");
    }
    assert!(
        out.status.success(),
        "the browser tests failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
}

/// The page's pure modules (the fisheye and value axes of HDR VolVis Eq. 2, the editor's
/// colour and opacity helpers) against their closed forms: `node --test view/tests/js/`.
#[test]
fn the_page_modules_pass_their_node_unit_tests() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let node = Command::new("node").arg("--version").output();
    if !node.as_ref().is_ok_and(|o| o.status.success()) {
        assert!(
            !required(),
            "BLUESHIFT_REQUIRE_BROWSER_TESTS=1 but node is missing"
        );
        println!("SKIP: node is missing");
        return;
    }
    let out = Command::new("node")
        .args(["--test", "view/tests/js/"])
        .current_dir(&root)
        .output()
        .expect("cannot run node");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "node --test view/tests/js/ failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
