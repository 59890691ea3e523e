//! Helpers shared by the integration tests.
#![allow(dead_code)]

/// Asserts |actual - expected| <= tol, printing both and the real difference.
#[track_caller]
pub fn assert_close(actual: f64, expected: f64, tol: f64, what: &str) {
    let diff = (actual - expected).abs();
    assert!(
        diff <= tol,
        "{what}: expected {expected}, got {actual}, |diff| = {diff:e} > tol {tol:e}"
    );
}
