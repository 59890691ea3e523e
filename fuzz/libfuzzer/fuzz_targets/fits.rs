//! libFuzzer target `fits`: [`blueshift_fuzz::fits`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::fits(data);
});
