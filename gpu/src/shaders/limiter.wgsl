// Probe of lavapipe's loop limiter, prepended by the crate to the shaders that call it
// (`LIMITER_WGSL`): llvmpipe keeps one loop limiter per invocation batch (the SIMD lanes that
// run together); every iteration of every loop of any lane counts, and after 65535 every loop
// exits at the end of its current iteration, silently (a ray would stop half-way, a sum come
// out short). This loop of `n` iterations (`n` = 2 from a uniform, so it is not unrolled)
// stops after one only when the limiter is spent, i.e. when some loop may have been cut
// short. Always false on other adapters.
fn limiter_exhausted(n: u32) -> bool {
    var k = 0u;
    loop {
        k += 1u;
        if k >= n { break; }
    }
    return k < n;
}
