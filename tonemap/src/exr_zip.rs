//! OpenEXR ZIP blocks decompressed in two passes rather than the exr crate's four: the
//! zlib stream inflated (by `zune-inflate`, the exr crate's inflater, with its checks), then
//! the compressor's byte predictor and byte reordering undone together, straight into the
//! block's samples, sixteen bytes of each half at a time (SSE2, part of every x86-64 CPU).
//!
//! OpenEXR's ZIP compressor (`ImfZip.cpp`) splits a block's bytes into its even-indexed
//! bytes then its odd-indexed ones, replaces each byte after the first by its difference
//! from the previous one plus 128 (mod 256), and deflates the result. Undone: the running
//! sum `p[i] = d[0] + (d[1] - 128) + ... + (d[i] - 128)` (mod 256) of the inflated bytes `d`
//! gives the split bytes; its first half are the even samples bytes, its second half the
//! odd ones.

/// A ZIP block's bytes, `expected` of them (the block's lines of samples, little-endian as
/// the file stores them). The error names what is wrong with the data.
pub(crate) fn decompress(data: &[u8], expected: usize) -> Result<Vec<u8>, &'static str> {
    let options = zune_inflate::DeflateOptions::default()
        .set_limit(expected)
        .set_size_hint(expected);
    let inflated = zune_inflate::DeflateDecoder::new_with_options(data, options)
        .decode_zlib()
        .map_err(|_| "zlib-compressed data malformed")?;
    if inflated.len() != expected {
        return Err("a block's data does not match its size");
    }
    let mut out = vec![0u8; expected];
    undo_predictor(&inflated, &mut out);
    Ok(out)
}

/// The predictor and the reordering of `d` undone into `out` (of the same length).
pub(crate) fn undo_predictor(d: &[u8], out: &mut [u8]) {
    let n = d.len();
    if n == 0 {
        return;
    }
    // The first half's bytes go to the even places, the second half's to the odd ones; the
    // second half's sum starts from the first half's last value, `p[half - 1]`: the bytes'
    // sum less 128 for each byte after the first.
    let half = n.div_ceil(2);
    let (a, b) = d.split_at(half);
    let sum = a.iter().fold(0u8, |s, &x| s.wrapping_add(x));
    let last_a = sum.wrapping_sub(((half - 1) as u8).wrapping_mul(128));
    // `d[0]` is the first value itself: a running sum from 128 adds it as `d[0] - 128`.
    let (mut ca, mut cb) = (128u8, last_a);
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    let done = {
        let done;
        // SAFETY: SSE2 is enabled for the whole build (as on every x86-64 target).
        #[allow(unsafe_code)]
        unsafe {
            (done, ca, cb) = sse2::pairs(a, b, ca, cb, out);
        }
        done
    };
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    let done = 0;
    for i in done..half {
        ca = ca.wrapping_add(a[i]).wrapping_sub(128);
        out[2 * i] = ca;
        if let Some(&x) = b.get(i) {
            cb = cb.wrapping_add(x).wrapping_sub(128);
            out[2 * i + 1] = cb;
        }
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
mod sse2 {
    use std::arch::x86_64::{
        __m128i, _mm_add_epi8, _mm_set1_epi8, _mm_shuffle_epi32, _mm_shufflehi_epi16,
        _mm_slli_si128, _mm_unpackhi_epi8, _mm_unpacklo_epi8, _mm_xor_si128,
    };

    /// Sixteen running sums of `x - 128` from `carry` (every lane), and the last of them in
    /// every lane.
    #[target_feature(enable = "sse2")]
    fn running(x: __m128i, carry: __m128i) -> (__m128i, __m128i) {
        // x - 128 = x ^ 128 (mod 256); then each lane plus the 1, 2, 4, 8 lanes before it.
        let mut s = _mm_xor_si128(x, _mm_set1_epi8(-128));
        s = _mm_add_epi8(s, _mm_slli_si128::<1>(s));
        s = _mm_add_epi8(s, _mm_slli_si128::<2>(s));
        s = _mm_add_epi8(s, _mm_slli_si128::<4>(s));
        s = _mm_add_epi8(s, _mm_slli_si128::<8>(s));
        let s = _mm_add_epi8(s, carry);
        // Byte 15 into every lane: bytes 8..16 doubled into words, word 7 into the upper
        // four words, their upper pair of words into all four 32-bit lanes.
        let hi = _mm_unpackhi_epi8(s, s);
        let last = _mm_shuffle_epi32::<0xff>(_mm_shufflehi_epi16::<0xff>(hi));
        (s, last)
    }

    /// [`super::undo_predictor`]'s loop over whole sixteens of both halves (`a`, `b`, the
    /// running sums `ca`, `cb` before them): how many places of each half it did, and the
    /// sums after them.
    #[target_feature(enable = "sse2")]
    pub(super) fn pairs(a: &[u8], b: &[u8], ca: u8, cb: u8, out: &mut [u8]) -> (usize, u8, u8) {
        let (a16, b16, o32) = (
            a.as_chunks::<16>().0,
            b.as_chunks::<16>().0,
            out.as_chunks_mut::<32>().0,
        );
        let mut ca = _mm_set1_epi8(ca as i8);
        let mut cb = _mm_set1_epi8(cb as i8);
        let mut done = 0;
        for ((x, y), o) in a16.iter().zip(b16).zip(o32) {
            let (sa, la) = running(bytemuck::cast(*x), ca);
            let (sb, lb) = running(bytemuck::cast(*y), cb);
            (ca, cb) = (la, lb);
            *o = bytemuck::cast([_mm_unpacklo_epi8(sa, sb), _mm_unpackhi_epi8(sa, sb)]);
            done += 16;
        }
        let first = |v: __m128i| bytemuck::cast::<__m128i, [u8; 16]>(v)[0];
        (done, first(ca), first(cb))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The running sum and the reordering written as OpenEXR's `ImfZip.cpp` writes them,
    /// one byte at a time.
    fn reference(d: &[u8]) -> Vec<u8> {
        let mut t = d.to_vec();
        for i in 1..t.len() {
            t[i] = t[i - 1].wrapping_add(t[i]).wrapping_sub(128);
        }
        let half = t.len().div_ceil(2);
        let mut out = vec![0u8; t.len()];
        for (i, o) in out.iter_mut().enumerate() {
            *o = if i % 2 == 0 {
                t[i / 2]
            } else {
                t[half + i / 2]
            };
        }
        out
    }

    #[test]
    fn the_predictor_is_undone_as_openexr_does() {
        let mut next = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        for n in (0..80).chain([255, 256, 257, 1000, 4097, 65_536 + 33]) {
            let d: Vec<u8> = (0..n).map(|_| (next() >> 24) as u8).collect();
            let mut out = vec![0u8; n];
            undo_predictor(&d, &mut out);
            assert_eq!(out, reference(&d), "{n} bytes");
        }
    }

    #[test]
    fn damaged_or_wrong_sized_streams_are_errors() {
        use std::io::Write;
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        z.write_all(&[7u8; 100]).unwrap();
        let good = z.finish().unwrap();
        assert_eq!(decompress(&good, 100).unwrap().len(), 100);
        assert!(decompress(&good, 99).is_err(), "longer than the block");
        assert!(decompress(&good, 101).is_err(), "shorter than the block");
        assert!(
            decompress(&good[..good.len() / 2], 100).is_err(),
            "truncated"
        );
        let mut bad = good.clone();
        let last = bad.len() - 1;
        bad[last] ^= 1;
        assert!(decompress(&bad, 100).is_err(), "checksum");
    }
}
