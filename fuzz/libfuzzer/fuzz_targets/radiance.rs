//! libFuzzer target `radiance`: [`blueshift_fuzz::radiance`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::radiance(data);
});
