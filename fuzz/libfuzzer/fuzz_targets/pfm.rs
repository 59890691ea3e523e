//! libFuzzer target `pfm`: [`blueshift_fuzz::pfm`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::pfm(data);
});
