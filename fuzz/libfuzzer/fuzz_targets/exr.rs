//! libFuzzer target `exr`: [`blueshift_fuzz::exr`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::exr(data);
});
