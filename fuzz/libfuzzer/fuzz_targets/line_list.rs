//! libFuzzer target `line_list`: [`blueshift_fuzz::line_list`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::line_list(data);
});
