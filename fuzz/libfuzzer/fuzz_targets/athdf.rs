//! libFuzzer target `athdf`: [`blueshift_fuzz::athdf`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::athdf(data);
});
