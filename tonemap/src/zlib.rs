//! The zlib stream of a PNG's pixel data, compressed in parallel.
//!
//! PNG stores its filtered rows as one zlib stream (RFC 1950 around RFC 1951 deflate). The
//! rows are cut into chunks of about [`CHUNK_BYTES`] (the cut depends on the image's size
//! only, so the bytes do not depend on the thread count), and each chunk is compressed on
//! its own into deflate blocks that end on a byte boundary (an empty stored block after
//! the chunk's block, as a "sync flush" leaves it), so the chunks' bytes simply follow one
//! another. The stream ends with an empty final stored block and the Adler-32 of all the
//! filtered rows (the chunks' checksums combined).
//!
//! Each chunk is one dynamic-Huffman block of literals and runs of zero bytes (a zero
//! followed by copies at distance 1), the two things PNG's Up-filtered rows of smooth
//! images are made of (the `fdeflate` crate's observation). Its code is built from the
//! symbol counts of the chunk's first rows, every symbol counted at least once so any
//! byte can follow, with codes of at most [`MAX_CODE`] bits. Rows are Up-filtered (the
//! filter blueshift writes every row with, [`crate::io::PNG_FILTER`]).

use rayon::prelude::*;

/// Filtered bytes per chunk (whole rows, at least one).
pub const CHUNK_BYTES: usize = 1 << 19;
/// Longest code (bits): four literals fit a 64-bit accumulator with a partial byte.
const MAX_CODE: u8 = 12;
/// Filtered bytes of each chunk whose symbols are counted for its code.
const SAMPLE_BYTES: usize = 1 << 16;
/// Zero runs at least this long are coded as a zero and copies.
const MIN_RUN: usize = 6;
/// PNG's Up filter type.
const UP: u8 = 2;

/// The zlib stream of the Up-filtered `height` rows of `row_bytes` bytes in `data`, as
/// parts to write one after the other (a PNG may split its stream over IDAT chunks
/// anywhere).
///
/// # Panics
/// If `data` is shorter than `height * row_bytes`.
#[must_use]
pub fn png_zlib_parts(data: &[u8], row_bytes: usize, height: usize) -> Vec<Vec<u8>> {
    assert!(
        row_bytes
            .checked_mul(height)
            .is_some_and(|n| n <= data.len()),
        "rows past the data"
    );
    png_zlib_parts_of(&SliceRows { data, row_bytes }, row_bytes, height)
}

/// Rows of unfiltered PNG bytes made on demand, by several threads at once (each with its
/// own [`PngRows::State`]): the rows are compressed while they are in the cache, and the
/// image need not be held whole.
pub trait PngRows: Sync {
    /// One thread's buffers.
    type State: Send;
    /// A new thread's buffers.
    fn state(&self) -> Self::State;
    /// Rows `from..to` (`to - from` rows of `row_bytes` bytes each, one after the other).
    fn rows<'s>(&'s self, state: &'s mut Self::State, from: usize, to: usize) -> &'s [u8];
}

struct SliceRows<'a> {
    data: &'a [u8],
    row_bytes: usize,
}

impl PngRows for SliceRows<'_> {
    type State = ();
    fn state(&self) {}
    fn rows<'s>(&'s self, (): &'s mut (), from: usize, to: usize) -> &'s [u8] {
        &self.data[from * self.row_bytes..to * self.row_bytes]
    }
}

/// [`png_zlib_parts`] of the rows `rows` makes: each chunk's rows (and the row above it, for
/// the filter) are asked for once, by the thread that compresses them.
///
/// # Panics
/// If `rows` gives a slice of another length than asked for.
#[must_use]
pub fn png_zlib_parts_of(rows: &impl PngRows, row_bytes: usize, height: usize) -> Vec<Vec<u8>> {
    let rows_per_chunk = (CHUNK_BYTES / (row_bytes + 1)).max(1);
    let starts: Vec<usize> = (0..height).step_by(rows_per_chunk).collect();
    let chunks: Vec<(Vec<u8>, u32, usize)> = starts
        .par_iter()
        .map_init(
            || (rows.state(), Vec::new(), Vec::new()),
            |(state, filtered, buf), &y0| {
                let y1 = (y0 + rows_per_chunk).min(height);
                let from = y0.saturating_sub(1);
                let bytes = rows.rows(state, from, y1);
                assert_eq!(
                    bytes.len(),
                    (y1 - from) * row_bytes,
                    "rows of the asked size"
                );
                filter_up(bytes, row_bytes, y1 - from, y0 > 0, filtered);
                let mut adler = simd_adler32::Adler32::new();
                adler.write(filtered);
                (
                    compress_chunk(filtered, buf),
                    adler.finish(),
                    filtered.len(),
                )
            },
        )
        .collect();
    let mut parts = Vec::with_capacity(chunks.len() + 2);
    // CMF: deflate, 32 KiB window; FLG: fastest compression level, check bits.
    parts.push(vec![0x78, 0x01]);
    let mut adler = 1u32;
    for (bytes, a, len) in chunks {
        adler = adler32_combine(adler, a, len);
        parts.push(bytes);
    }
    // An empty final stored block, then the checksum (big-endian).
    let mut end = vec![0x01, 0x00, 0x00, 0xff, 0xff];
    end.extend_from_slice(&adler.to_be_bytes());
    parts.push(end);
    parts
}

/// The `count` rows of `rows` Up-filtered into `out`: each row its filter byte, then each
/// byte minus the byte above (0 above the image's first row). If `above`, the first row of
/// `rows` is only the one above the others (not written).
fn filter_up(rows: &[u8], row_bytes: usize, count: usize, above: bool, out: &mut Vec<u8>) {
    out.clear();
    out.reserve(count * (row_bytes + 1));
    let row = |i: usize| &rows[i * row_bytes..(i + 1) * row_bytes];
    for i in usize::from(above)..count {
        out.push(UP);
        if i == 0 {
            out.extend_from_slice(row(i));
        } else {
            out.extend(
                row(i)
                    .iter()
                    .zip(row(i - 1))
                    .map(|(&a, &b)| a.wrapping_sub(b)),
            );
        }
    }
}

/// Adler-32 of `A` then `B` from `adler(A)`, `adler(B)` and `B`'s length (RFC 1950's sums:
/// `s1 = 1 + sum`, `s2 = sum of the running s1`, both mod 65521).
fn adler32_combine(a: u32, b: u32, len_b: usize) -> u32 {
    const M: u64 = 65521;
    let (a1, a2) = (u64::from(a & 0xffff), u64::from(a >> 16));
    let (b1, b2) = (u64::from(b & 0xffff), u64::from(b >> 16));
    let n = len_b as u64 % M;
    let s1 = (a1 + b1 + M - 1) % M;
    let s2 = (a2 + b2 + n * ((a1 + M - 1) % M)) % M;
    ((s2 << 16) | s1) as u32
}

/// What a chunk's bytes are coded as.
trait Tokens {
    fn literal(&mut self, b: u8);
    /// A copy of `len` (3..=258) bytes at distance 1.
    fn copy(&mut self, len: usize);
    /// Literals, in order.
    #[inline(always)]
    fn literals(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.literal(b);
        }
    }
    /// `run` zero bytes: a zero and copies of it when the run is long enough.
    #[inline(always)]
    fn zeros(&mut self, run: usize) {
        if run < MIN_RUN {
            for _ in 0..run {
                self.literal(0);
            }
            return;
        }
        self.literal(0);
        let mut left = run - 1;
        while left >= 3 {
            let l = left.min(258);
            self.copy(l);
            left -= l;
        }
        for _ in 0..left {
            self.literal(0);
        }
    }
}

/// Feeds `data` to `t` 8 bytes at a time: zero bytes at the ends of a word join the runs
/// of zeros around it (whole zero words extend them), every other byte is a literal (a
/// zero inside a word too), so a word costs no per-byte branch.
#[inline(always)]
fn tokenize(data: &[u8], t: &mut impl Tokens) {
    let mut run = 0usize;
    let mut words = data.chunks_exact(8);
    for w in &mut words {
        let x = u64::from_le_bytes(w.try_into().expect("8 bytes"));
        if x == 0 {
            run += 8;
            continue;
        }
        // Zero bytes first in memory are the low ones (little-endian).
        let lead = (x.trailing_zeros() / 8) as usize;
        let tail = (x.leading_zeros() / 8) as usize;
        if run + lead > 0 {
            t.zeros(run + lead);
        }
        t.literals(&w[lead..8 - tail]);
        run = tail;
    }
    for &b in words.remainder() {
        if b == 0 {
            run += 1;
        } else {
            if run > 0 {
                t.zeros(run);
            }
            run = 0;
            t.literal(b);
        }
    }
    if run > 0 {
        t.zeros(run);
    }
}

/// Length symbol (257..=285), its extra bits and their value, for a copy length 3..=258
/// (RFC 1951 3.2.5).
fn length_code(len: usize) -> (usize, u8, u32) {
    const BASE: [u16; 29] = [
        3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115,
        131, 163, 195, 227, 258,
    ];
    const EXTRA: [u8; 29] = [
        0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
    ];
    // Each length's entry of `BASE`, built once at compile time (a search per copy was a
    // tenth of the compression's time): the last base at or below it, 258 its own.
    const INDEX: [u8; 259] = {
        let mut t = [0u8; 259];
        let mut len = 3;
        while len <= 258 {
            let mut i = 0;
            while i + 1 < 29 && BASE[i + 1] as usize <= len {
                i += 1;
            }
            t[len] = i as u8;
            len += 1;
        }
        t
    };
    let i = usize::from(INDEX[len]);
    (257 + i, EXTRA[i], (len - usize::from(BASE[i])) as u32)
}

/// Symbol counts of the literal/length alphabet.
struct Counts([u32; 286]);

impl Tokens for Counts {
    fn literal(&mut self, b: u8) {
        self.0[usize::from(b)] += 1;
    }
    fn copy(&mut self, len: usize) {
        self.0[length_code(len).0] += 1;
    }
}

/// Huffman code lengths for `freq` (every used symbol gets a code, none longer than
/// `limit`): the Huffman tree's depths, with the counts halved (rounding up, so no used
/// symbol is lost) until the deepest leaf fits. At least two symbols get codes (a code of
/// one symbol is padded with a second), so the code is complete.
fn code_lengths(freq: &[u32], limit: u8) -> Vec<u8> {
    let mut f: Vec<u64> = freq.iter().map(|&x| u64::from(x)).collect();
    if f.iter().filter(|&&x| x > 0).count() < 2 {
        let spare = usize::from(f.first().is_some_and(|&x| x > 0));
        f[spare] = f[spare].max(1);
        if f.iter().filter(|&&x| x > 0).count() < 2 {
            let other = f
                .iter()
                .position(|&x| x == 0)
                .expect("two symbols at least");
            f[other] = 1;
        }
    }
    loop {
        let lens = huffman_depths(&f);
        if lens.iter().all(|&l| l <= limit) {
            return lens;
        }
        for x in f.iter_mut().filter(|x| **x > 0) {
            *x = x.div_ceil(2);
        }
    }
}

/// The depth of each used symbol in a Huffman tree of the counts `f` (0 for unused ones),
/// ties broken by node order so the result is deterministic.
fn huffman_depths(f: &[u64]) -> Vec<u8> {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let mut parent: Vec<usize> = Vec::with_capacity(2 * f.len());
    let mut heap = BinaryHeap::new();
    for (i, &x) in f.iter().enumerate() {
        parent.push(usize::MAX);
        if x > 0 {
            heap.push(Reverse((x, i)));
        }
    }
    while heap.len() > 1 {
        let Reverse((a, i)) = heap.pop().expect("two nodes");
        let Reverse((b, j)) = heap.pop().expect("two nodes");
        let node = parent.len();
        parent.push(usize::MAX);
        parent[i] = node;
        parent[j] = node;
        heap.push(Reverse((a + b, node)));
    }
    // Depths from the root down: a node's parent comes after it.
    let mut depth = vec![0u8; parent.len()];
    for n in (0..parent.len()).rev() {
        if parent[n] != usize::MAX {
            depth[n] = depth[parent[n]].saturating_add(1);
        }
    }
    (0..f.len())
        .map(|i| if f[i] > 0 { depth[i] } else { 0 })
        .collect()
}

/// Canonical codes (RFC 1951 3.2.2) for `lens`, bit-reversed for LSB-first output.
fn canonical_codes(lens: &[u8]) -> Vec<u16> {
    let mut count = [0u16; 16];
    for &l in lens {
        count[usize::from(l)] += 1;
    }
    count[0] = 0;
    let mut next = [0u16; 16];
    let mut code = 0u16;
    for bits in 1..16 {
        code = (code + count[bits - 1]) << 1;
        next[bits] = code;
    }
    lens.iter()
        .map(|&l| {
            if l == 0 {
                return 0;
            }
            let c = next[usize::from(l)];
            next[usize::from(l)] += 1;
            c.reverse_bits() >> (16 - l)
        })
        .collect()
}

/// Bits written least significant first into a buffer sized for the worst case (no
/// growth, so the state stays in registers in the coding loop).
struct Bits<'a> {
    /// The bytes written are `out[..pos]`; callers keep 8 bytes of room past `pos`.
    out: &'a mut [u8],
    pos: usize,
    acc: u64,
    n: u32,
}

impl Bits<'_> {
    /// Adds `n` bits (`n + self.n <= 64`).
    #[inline(always)]
    fn put(&mut self, bits: u64, n: u32) {
        self.acc |= bits << self.n;
        self.n += n;
    }

    /// Moves the whole bytes out (leaves at most 7 bits): one 8-byte store.
    #[inline(always)]
    fn flush(&mut self) {
        self.out[self.pos..self.pos + 8].copy_from_slice(&self.acc.to_le_bytes());
        let bytes = self.n / 8;
        self.pos += bytes as usize;
        self.acc = if bytes == 8 {
            0
        } else {
            self.acc >> (8 * bytes)
        };
        self.n -= 8 * bytes;
    }

    /// [`Bits::put`] then [`Bits::flush`].
    #[inline(always)]
    fn write(&mut self, bits: u64, n: u32) {
        self.put(bits, n);
        self.flush();
    }

    /// Pads to a byte boundary.
    fn align(&mut self) {
        let pad = (8 - self.n % 8) % 8;
        self.write(0, pad);
    }
}

/// The chunk's block writer: its literal/length code and the bits.
struct Encoder<'a, 'b> {
    bits: Bits<'b>,
    /// Each literal's code and length together (`code | len << 16`).
    lit: &'a [u32; 256],
    code: &'a [u16],
    len: &'a [u8],
}

impl Encoder<'_, '_> {
    #[inline(always)]
    fn put_literal(&mut self, b: u8) {
        let e = self.lit[usize::from(b)];
        self.bits.put(u64::from(e & 0xffff), e >> 16);
    }
}

impl Tokens for Encoder<'_, '_> {
    #[inline(always)]
    fn literal(&mut self, b: u8) {
        self.put_literal(b);
        self.bits.flush();
    }

    /// Four codes of at most 12 bits after at most 7 left over: a flush every fourth.
    #[inline(always)]
    fn literals(&mut self, bytes: &[u8]) {
        let mut quads = bytes.chunks_exact(4);
        for q in &mut quads {
            // The four codes joined pairwise (independent steps) before one put: the
            // accumulator's chain of shifts is one step per four literals.
            let e = [q[0], q[1], q[2], q[3]].map(|b| self.lit[usize::from(b)]);
            let code = |e: u32| u64::from(e & 0xffff);
            let (l0, l2) = (e[0] >> 16, e[2] >> 16);
            let (l01, l23) = (l0 + (e[1] >> 16), l2 + (e[3] >> 16));
            let c01 = code(e[0]) | code(e[1]) << l0;
            let c23 = code(e[2]) | code(e[3]) << l2;
            self.bits.put(c01 | c23 << l01, l01 + l23);
            self.bits.flush();
        }
        for &b in quads.remainder() {
            self.put_literal(b);
        }
        self.bits.flush();
    }

    #[inline(always)]
    fn copy(&mut self, len: usize) {
        let (s, extra_bits, extra) = length_code(len);
        self.bits
            .put(u64::from(self.code[s]), u32::from(self.len[s]));
        self.bits.put(u64::from(extra), u32::from(extra_bits));
        // Distance code 0 (distance 1): the 1-bit code 0.
        self.bits.put(0, 1);
        self.bits.flush();
    }
}

/// One chunk: a dynamic-Huffman block (not final) and an empty stored block, ending on a
/// byte boundary. `buf` is scratch.
fn compress_chunk(data: &[u8], buf: &mut Vec<u8>) -> Vec<u8> {
    let mut counts = Counts([1; 286]);
    let sample = &data[..data.len().min(SAMPLE_BYTES)];
    tokenize(sample, &mut counts);
    let lit_len = code_lengths(&counts.0, MAX_CODE);
    let lit_code = canonical_codes(&lit_len);
    let mut lit = [0u32; 256];
    for (b, e) in lit.iter_mut().enumerate() {
        *e = u32::from(lit_code[b]) | u32::from(lit_len[b]) << 16;
    }
    // Worst case: every byte a 12-bit literal, the header, 8 bytes of room.
    let need = data.len() * 3 / 2 + 1024;
    if buf.len() < need {
        buf.resize(need, 0);
    }
    let mut bits = Bits {
        out: buf,
        pos: 0,
        acc: 0,
        n: 0,
    };
    // Block header: not final, dynamic Huffman.
    bits.write(0b100, 3);
    write_code_lengths(&mut bits, &lit_len);
    let mut enc = Encoder {
        bits,
        lit: &lit,
        code: &lit_code,
        len: &lit_len,
    };
    tokenize(data, &mut enc);
    let mut bits = enc.bits;
    // End of block, then an empty stored block (not final) to reach a byte boundary.
    bits.write(u64::from(lit_code[256]), u32::from(lit_len[256]));
    bits.write(0, 3);
    bits.align();
    let end = bits.pos;
    let mut out = Vec::with_capacity(end + 4);
    out.extend_from_slice(&bits.out[..end]);
    out.extend_from_slice(&[0x00, 0x00, 0xff, 0xff]);
    out
}

/// The dynamic block's code description (RFC 1951 3.2.7): the 286 literal/length lengths
/// (trailing unused ones dropped, at least 257), two distance codes of one bit, all coded
/// with the code-length alphabet (lengths 0..15, 17 and 18 for runs of zeros).
fn write_code_lengths(bits: &mut Bits<'_>, lit_len: &[u8]) {
    let nlit = lit_len
        .iter()
        .rposition(|&l| l > 0)
        .map_or(257, |i| (i + 1).max(257));
    let mut all: Vec<u8> = lit_len[..nlit].to_vec();
    all.extend_from_slice(&[1, 1]);
    // (symbol, extra bits, extra value)
    let mut syms: Vec<(usize, u32, u32)> = Vec::new();
    let mut i = 0;
    while i < all.len() {
        let l = all[i];
        let mut run = 1;
        while i + run < all.len() && all[i + run] == l {
            run += 1;
        }
        if l == 0 && run >= 3 {
            let r = run.min(138);
            if r >= 11 {
                syms.push((18, 7, (r - 11) as u32));
            } else {
                syms.push((17, 3, (r - 3) as u32));
            }
            i += r;
        } else {
            syms.push((usize::from(l), 0, 0));
            i += 1;
        }
    }
    let mut freq = [0u32; 19];
    for &(s, _, _) in &syms {
        freq[s] += 1;
    }
    let cl_len = code_lengths(&freq, 7);
    let cl_code = canonical_codes(&cl_len);
    const ORDER: [usize; 19] = [
        16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15,
    ];
    let nclen = ORDER
        .iter()
        .rposition(|&s| cl_len[s] > 0)
        .map_or(4, |i| (i + 1).max(4));
    bits.write((nlit - 257) as u64, 5);
    bits.write(1, 5); // HDIST: two distance codes.
    bits.write((nclen - 4) as u64, 4);
    for &s in &ORDER[..nclen] {
        bits.write(u64::from(cl_len[s]), 3);
    }
    for (s, n, v) in syms {
        bits.write(u64::from(cl_code[s]), u32::from(cl_len[s]));
        bits.write(u64::from(v), n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every copy length's symbol, extra bits and value are RFC 1951's (3.2.5): the
    /// symbol's base plus the extra value gives the length back, within the symbol's range.
    #[test]
    fn length_codes_are_rfc_1951s() {
        // (symbol, extra bits, first length), from the RFC's table.
        let table: Vec<(usize, u8, usize)> = (257..=285)
            .map(|s| {
                let extra = match s {
                    257..=264 | 285 => 0,
                    _ => ((s - 261) / 4) as u8,
                };
                (s, extra, 0)
            })
            .scan(3usize, |next, (s, extra, _)| {
                let first = if s == 285 { 258 } else { *next };
                *next = first + (1 << extra);
                Some((s, extra, first))
            })
            .collect();
        for len in 3..=258 {
            let (s, extra, value) = length_code(len);
            let &(_, want_extra, first) = table.iter().find(|t| t.0 == s).unwrap();
            assert_eq!(extra, want_extra, "length {len}");
            assert!(value < 1 << extra, "length {len}");
            assert_eq!(first + value as usize, len, "length {len}");
        }
    }

    #[test]
    fn adler32_combined_equals_the_whole() {
        let data: Vec<u8> = (0..200_000u32).map(|i| (i * 7919 % 251) as u8).collect();
        for cut in [0, 1, 5552, 65521, 100_000, 200_000] {
            let (a, b) = data.split_at(cut);
            let whole = simd_adler32::adler32(&data.as_slice());
            let parts = adler32_combine(
                simd_adler32::adler32(&a),
                simd_adler32::adler32(&b),
                b.len(),
            );
            assert_eq!(parts, whole, "cut at {cut}");
        }
    }

    #[test]
    fn length_codes_follow_rfc1951() {
        assert_eq!(length_code(3), (257, 0, 0));
        assert_eq!(length_code(10), (264, 0, 0));
        assert_eq!(length_code(11), (265, 1, 0));
        assert_eq!(length_code(12), (265, 1, 1));
        assert_eq!(length_code(18), (268, 1, 1));
        assert_eq!(length_code(19), (269, 2, 0));
        assert_eq!(length_code(130), (280, 4, 15));
        assert_eq!(length_code(131), (281, 5, 0));
        assert_eq!(length_code(257), (284, 5, 30));
        assert_eq!(length_code(258), (285, 0, 0));
    }

    #[test]
    fn code_lengths_are_complete_and_bounded() {
        // Kraft's sum is exactly 1 (a complete prefix code) and no code exceeds the limit,
        // for skewed (Fibonacci) counts that an unbounded Huffman code makes 20+ deep.
        let mut fib = vec![1u32, 1];
        while fib.len() < 30 {
            let n = fib.len();
            fib.push(fib[n - 1] + fib[n - 2]);
        }
        for (freq, limit) in [
            (fib.clone(), 12u8),
            (fib, 7),
            (vec![5, 0, 0, 0], 12),
            (vec![0, 0, 9, 0], 7),
            (vec![0; 19], 7),
        ] {
            let lens = code_lengths(&freq, limit);
            assert!(lens.iter().all(|&l| l <= limit));
            let kraft: f64 = lens
                .iter()
                .filter(|&&l| l > 0)
                .map(|&l| 0.5f64.powi(i32::from(l)))
                .sum();
            assert!((kraft - 1.0).abs() < 1e-12, "{lens:?}");
            for (f, l) in freq.iter().zip(&lens) {
                assert!(*f == 0 || *l > 0, "a used symbol without a code");
            }
        }
    }
}
