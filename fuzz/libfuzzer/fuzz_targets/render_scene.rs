//! libFuzzer target `render_scene`: [`blueshift_fuzz::render_scene`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::render_scene(data);
});
