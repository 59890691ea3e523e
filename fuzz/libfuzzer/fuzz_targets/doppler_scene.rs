//! libFuzzer target `doppler_scene`: [`blueshift_fuzz::doppler_scene`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::doppler_scene(data);
});
