//! libFuzzer target `bsv`: [`blueshift_fuzz::bsv`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::bsv(data);
});
