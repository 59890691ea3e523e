//! `blueshift gpu-info`: reports the adapter (lavapipe in CI) or fails with a one-line error.

use std::process::Command;

fn require() -> bool {
    std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1")
}

#[test]
fn gpu_info_json_reports_adapter_and_limits() {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["gpu-info", "--json", "--check", "--all"])
        .output()
        .unwrap();
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!require(), "gpu-info failed: {err}");
        assert!(err.contains("no wgpu adapter"), "{err}");
        eprintln!("SKIP: no wgpu adapter: {err}");
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(!v["name"].as_str().unwrap().is_empty());
    assert!(
        v["limits"]["max_storage_buffer_binding_size"]
            .as_u64()
            .unwrap()
            > 0
    );
    assert_eq!(v["check"], serde_json::json!(true));
    assert!(!v["adapters"].as_array().unwrap().is_empty());
}

#[test]
fn gpu_info_with_an_unknown_adapter_fails_cleanly() {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["gpu-info", "--adapter", "no-such-adapter-xyz"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no wgpu adapter"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}
