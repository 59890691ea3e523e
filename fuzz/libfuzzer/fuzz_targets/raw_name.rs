//! libFuzzer target `raw_name`: [`blueshift_fuzz::raw_name`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::raw_name(data);
});
