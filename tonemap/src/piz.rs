//! OpenEXR PIZ decompression of one scan-line block, written for speed: the format of the
//! OpenEXR specification (and of `ImfPizCompressor` / `ImfHuf` / `ImfWav` in OpenEXR),
//! decoded as the exr crate decodes it, value for value
//! (`io::tests::exr_blocks_equal_the_exr_crates_reader`), but with the Huffman codes read
//! through a 64-bit window and two levels of tables (12 bits, then up to 12 more), the wavelet undone without
//! per-sample checks, and the channels left as planes for the caller to convert.
//!
//! A block holds, in order: the bitmap of the 16-bit values that occur (their range of
//! bytes, then the bytes), the Huffman data's length, and the Huffman data (a header of five
//! 32-bit words, the code lengths packed with runs of zeros, then the codes, most significant
//! bit first, with one symbol meaning "repeat the last value n times"). Decoded, the values
//! are indices into the sorted list of values that occur; before that lookup, each channel's
//! plane (and each 16-bit half of 32-bit samples) is a 2D Haar-like wavelet transform to
//! undo.

/// Why a PIZ block could not be decoded (the file is damaged).
pub(crate) type PizError = &'static str;

const BITMAP_BYTES: usize = 1 << 13;
/// Symbols 0..=65535 and the run-length code, which may be 65536.
const SYMBOLS: usize = (1 << 16) + 1;
const SHORT_ZERO_RUN: u64 = 59;
const LONG_ZERO_RUN: u64 = 63;
/// Blocks of at least this many values get pairs of codes in the `fast` table.
const PAIRS_FROM: usize = 1 << 12;
const SHORTEST_LONG_RUN: usize = 2 + (LONG_ZERO_RUN - SHORT_ZERO_RUN) as usize;

/// Decodes one PIZ block of `lines` lines of `width` pixels whose channels take
/// `words[c]` 16-bit words per sample (1 for half, 2 for float and uint). Returns the
/// channels' planes one after another, each `lines * width * words[c]` words, line by line
/// (the two words of a 32-bit sample are its low and high halves), as indices into the
/// values that occur: the caller looks them up (in one step with the conversion to f32).
pub(crate) fn decompress(
    data: &[u8],
    words: &[usize],
    width: usize,
    lines: usize,
) -> Result<Decoded, PizError> {
    let total: usize = words.iter().map(|&k| k * width * lines).sum();
    let mut rest = data;
    let min_nz = usize::from(u16::from_le_bytes(take::<2>(&mut rest)?));
    let max_nz = usize::from(u16::from_le_bytes(take::<2>(&mut rest)?));
    if min_nz >= BITMAP_BYTES || max_nz >= BITMAP_BYTES {
        return Err("PIZ bitmap range out of bounds");
    }
    let mut bitmap = [0u8; BITMAP_BYTES];
    if min_nz <= max_nz {
        let n = max_nz - min_nz + 1;
        if rest.len() < n {
            return Err("PIZ bitmap truncated");
        }
        bitmap[min_nz..=max_nz].copy_from_slice(&rest[..n]);
        rest = &rest[n..];
    }
    // The values that occur, in order (0 always): decoded values index this list.
    let mut lut = SPARE_VALUES.take();
    if lut.len() != 1 << 16 {
        lut = vec![0u16; 1 << 16];
    }
    let mut count = 1usize;
    bitmap[0] &= !1;
    // (Up to the last byte that may be set: small tiles' values fill a few bytes.)
    let last = if min_nz <= max_nz { max_nz + 1 } else { 0 };
    for (i, &byte) in bitmap.iter().enumerate().take(last).skip(min_nz) {
        let mut bits = byte;
        while bits != 0 {
            lut[count] = (i * 8 + bits.trailing_zeros() as usize) as u16;
            count += 1;
            bits &= bits - 1;
        }
    }
    let max_value = (count - 1) as u16;
    // The Huffman data's length, which the decoder does not need (it reads the bit count).
    take::<4>(&mut rest)?;
    let mut planes = decode_huffman(rest, total)?;
    let mut at = 0;
    for &k in words {
        let n = k * width * lines;
        let plane = &mut planes[at..at + n];
        for half in 0..k {
            undo_wavelet(plane, half, k, width, lines, max_value < 1 << 14);
        }
        at += n;
    }
    Ok(Decoded {
        planes,
        values: lut,
        count,
    })
}

/// A decoded block: the planes hold indices into `values`, the 16-bit values that occur in
/// order, then zeros (one entry for every 16-bit index).
#[derive(Debug)]
pub(crate) struct Decoded {
    pub(crate) planes: Vec<u16>,
    pub(crate) values: Vec<u16>,
    /// How many of `values` are the values that occur (the rest are 0).
    count: usize,
}

thread_local! {
    /// A value table that a block decoded on this thread gave back, zero again: the next
    /// block's (a table is 128 KiB, and an 8-megapixel image of 64 x 64 tiles has 2,040
    /// blocks).
    static SPARE_VALUES: std::cell::Cell<Vec<u16>> = const { std::cell::Cell::new(Vec::new()) };
}

impl Decoded {
    /// Gives `values` back for the next block decoded on this thread (when the caller has
    /// looked up every index it needs).
    pub(crate) fn recycle_values(&mut self) {
        let mut values = std::mem::take(&mut self.values);
        if values.len() == 1 << 16 {
            values[..self.count].fill(0);
            SPARE_VALUES.set(values);
        }
    }
}

fn take<const N: usize>(rest: &mut &[u8]) -> Result<[u8; N], PizError> {
    let (head, tail) = rest.split_first_chunk::<N>().ok_or("PIZ block truncated")?;
    *rest = tail;
    Ok(*head)
}

/// The Huffman stream of `data` decoded to exactly `n` 16-bit values.
fn decode_huffman(data: &[u8], n: usize) -> Result<Vec<u16>, PizError> {
    let mut rest = data;
    let im = u32::from_le_bytes(take::<4>(&mut rest)?) as usize;
    let i_max = u32::from_le_bytes(take::<4>(&mut rest)?) as usize;
    take::<4>(&mut rest)?; // The table's length in bytes.
    let nbits = u32::from_le_bytes(take::<4>(&mut rest)?) as usize;
    take::<4>(&mut rest)?;
    if im >= SYMBOLS || i_max >= SYMBOLS || im > i_max {
        return Err("PIZ Huffman symbol range out of bounds");
    }
    // The code lengths, six bits each, with runs of zero lengths; bytes are fetched only
    // as bits are needed, and the codes start at the next byte.
    let mut coded: Vec<(u32, u8)> = Vec::new();
    let mut per_length = [0u64; 59];
    let (mut bits, mut have, mut pos) = (0u64, 0u32, 0usize);
    let mut read = |k: u32| -> Result<u64, PizError> {
        while have < k {
            let b = *rest.get(pos).ok_or("PIZ Huffman table truncated")?;
            bits = (bits << 8) | u64::from(b);
            pos += 1;
            have += 8;
        }
        have -= k;
        Ok((bits >> have) & ((1 << k) - 1))
    };
    let mut s = im;
    while s <= i_max {
        let l = read(6)?;
        let zeros = if l == LONG_ZERO_RUN {
            read(8)? as usize + SHORTEST_LONG_RUN
        } else if l >= SHORT_ZERO_RUN {
            (l - SHORT_ZERO_RUN) as usize + 2
        } else {
            if l > 0 {
                coded.push((s as u32, l as u8));
                per_length[l as usize] += 1;
            }
            s += 1;
            continue;
        };
        if s + zeros > i_max + 1 {
            return Err("PIZ Huffman table longer than its symbols");
        }
        s += zeros;
    }
    let codes = &rest[pos..];
    if nbits.div_ceil(8) > codes.len() {
        return Err("PIZ Huffman data truncated");
    }
    let table = Table::new(&coded, &per_length, i_max as u32, n >= PAIRS_FROM)?;
    table.decode(&codes[..nbits.div_ceil(8)], nbits, i_max as u32, n)
}

/// The decoding table, in two levels. `first[top 12 bits]` is `symbol << 8 | length` for
/// codes of at most 12 bits (0 where no code starts), or `at << 8 | 0x80 | bits` for the
/// prefixes of longer codes: their entries are `second[at + next bits]`, `symbol << 8 |
/// length` for codes of at most 24 bits, [`SCAN`] where a longer code starts (found by
/// scanning `scan`, for these rare codes of up to 58 bits).
struct Table {
    first: Vec<u32>,
    second: Vec<u32>,
    scan: Vec<(u64, u32, u32)>,
    /// Indexed like `first`, for the unchecked loop: `symbol_1 | symbol_2 << 16 | length
    /// << 32 | count << 40`, one code (count 1) or, in large blocks, two whole codes (count
    /// 2, neither the run code) in the 12 bits; [`SLOW`] where the first code is longer, the
    /// run code or no code.
    fast: Vec<u64>,
}

const FIRST_BITS: u32 = 12;
const TWO_LEVEL_BITS: u32 = 24;
const SCAN: u32 = 0xff;
/// A `fast` entry that the unchecked loop leaves to the checked step.
const SLOW: u64 = 1 << 48;

impl Table {
    /// The canonical codes of the symbols `coded` of lengths (OpenEXR's assignment: the
    /// codes of each length are consecutive in symbol order, longer lengths take the lower
    /// numbers), `per_length` of each length; `rlc` the run code; `pairs`: whether `fast`
    /// holds pairs of codes (worth building for large blocks only).
    fn new(
        coded: &[(u32, u8)],
        per_length: &[u64; 59],
        rlc: u32,
        pairs: bool,
    ) -> Result<Self, PizError> {
        let mut next = [0u64; 59];
        let mut code = 0u64;
        for l in (1..59).rev() {
            next[l] = code;
            code = (code + per_length[l]) >> 1;
        }
        // Each symbol's code, and for each first-level prefix the longest code under it.
        let mut codes = Vec::with_capacity(coded.len());
        let mut longest = [0u8; 1 << FIRST_BITS];
        // The prefixes of long codes (few: most blocks have none).
        let mut prefixes = Vec::new();
        for &(s, l) in coded {
            let l32 = u32::from(l);
            let code = next[usize::from(l)];
            next[usize::from(l)] += 1;
            if code >> l32 != 0 {
                return Err("PIZ Huffman code table invalid");
            }
            if l32 > FIRST_BITS {
                let prefix = (code >> (l32 - FIRST_BITS)) as usize;
                if longest[prefix] == 0 {
                    prefixes.push(prefix);
                }
                longest[prefix] = longest[prefix].max(l);
            }
            codes.push((code, l32, s));
        }
        let mut first = vec![0u32; 1 << FIRST_BITS];
        let mut second = Vec::new();
        prefixes.sort_unstable();
        for prefix in prefixes {
            let bits = u32::from(longest[prefix]).min(TWO_LEVEL_BITS) - FIRST_BITS;
            first[prefix] = ((second.len() as u32) << 8) | 0x80 | bits;
            second.resize(second.len() + (1 << bits), 0);
        }
        let mut scan = Vec::new();
        // The `fast` entries of single codes as the codes are placed (the table is built for
        // every block, and small tiles decode few values with it).
        let mut fast = vec![SLOW; 1 << FIRST_BITS];
        for &(code, l, s) in &codes {
            if l <= FIRST_BITS {
                let at = (code << (FIRST_BITS - l)) as usize;
                let span = at..at + (1 << (FIRST_BITS - l));
                // (A fold, which vectorises, rather than a check per entry.)
                if first[span.clone()].iter().fold(0, |a, e| a | e) & 0x80 != 0 {
                    return Err("PIZ Huffman code table invalid");
                }
                first[span.clone()].fill((s << 8) | l);
                // (Pairs are placed below, over the same entries.) The run code's entries are
                // left to the checked step, here too: a damaged table's run code may overlap
                // a code placed before it.
                if !pairs {
                    fast[span].fill(if s == rlc {
                        SLOW
                    } else {
                        u64::from(s) | u64::from(l) << 32 | 1 << 40
                    });
                }
                continue;
            }
            let prefix = (code >> (l - FIRST_BITS)) as usize;
            let e = first[prefix];
            let (base, bits) = ((e >> 8) as usize, e & 0x7f);
            let rest = l - FIRST_BITS;
            if rest <= bits {
                let at = base + ((code & ((1 << rest) - 1)) << (bits - rest)) as usize;
                second[at..at + (1 << (bits - rest))].fill((s << 8) | l);
            } else {
                let at = base + ((code >> (rest - bits)) & ((1 << bits) - 1)) as usize;
                second[at] = SCAN;
                scan.push((code, l, s));
            }
        }
        if pairs {
            // The entry `rest` of a code's span pairs the code with the one that starts at
            // its remaining bits, `first[rest << l]` for a code of `l` bits: the same for
            // every code of that length but for the code's own symbol. So one template per
            // length present (the entries without the symbol), then each code's span is its
            // template with the symbol ORed in: the table is built for every block, and a
            // tile's is a tenth of its decoding.
            let short = |e: u32| (e & 0x80 == 0) & (e & 0xff != 0) & (e >> 8 != rlc);
            let mut template = Vec::new();
            let mut starts = [0usize; FIRST_BITS as usize + 1];
            for l in 1..=FIRST_BITS {
                starts[l as usize] = template.len();
                if per_length[l as usize] == 0 {
                    continue;
                }
                template.extend((0..1usize << (FIRST_BITS - l)).map(|rest| {
                    let b = first[(rest << l) & ((1 << FIRST_BITS) - 1)];
                    let lb = b & 0xff;
                    if short(b) & (l + lb <= FIRST_BITS) {
                        u64::from(b >> 8) << 16 | u64::from(l + lb) << 32 | 2 << 40
                    } else {
                        u64::from(l) << 32 | 1 << 40
                    }
                }));
            }
            // Code by code, in the order they were placed (a damaged table's overlapping codes
            // then leave `fast` as they leave `first`).
            for &(code, l, s) in &codes {
                if l > FIRST_BITS {
                    continue;
                }
                let at = (code << (FIRST_BITS - l)) as usize;
                let span = 1 << (FIRST_BITS - l);
                if s == rlc {
                    fast[at..at + span].fill(SLOW);
                    continue;
                }
                let from = &template[starts[l as usize]..][..span];
                for (f, t) in fast[at..at + span].iter_mut().zip(from) {
                    *f = t | u64::from(s);
                }
            }
        }
        Ok(Table {
            first,
            second,
            scan,
            fast,
        })
    }

    /// Decodes the first `nbits` bits of `codes` to exactly `n` values; `rlc` is the
    /// symbol followed by an 8-bit count of repeats of the last value.
    fn decode(&self, codes: &[u8], nbits: usize, rlc: u32, n: usize) -> Result<Vec<u16>, PizError> {
        // The codes with eight zero bytes after them, and the bits past `nbits` cleared,
        // so that a window of 64 bits can be loaded at any bit before the end.
        let mut buf = Vec::with_capacity(codes.len() + 8);
        buf.extend_from_slice(codes);
        if !nbits.is_multiple_of(8)
            && let Some(last) = buf.last_mut()
        {
            *last &= 0xffu8 << (8 - nbits % 8);
        }
        buf.extend_from_slice(&[0; 8]);
        // 64 bits from bit `pos` on, of which at least the first 57 are the data's.
        let window = |pos: usize| -> u64 {
            let at = pos >> 3;
            buf.get(at..at + 8)
                .and_then(|b| b.try_into().ok())
                .map_or(0, u64::from_be_bytes)
                << (pos & 7)
        };
        let mut out = vec![0u16; n];
        let mut k = 0usize;
        // `w` holds the bits from `base` on; `used` of them are decoded.
        let (mut base, mut used) = (0usize, 0u32);
        let mut w = window(0);
        // Far from the ends of the data and of the block, short codes need no checks (the
        // inner loop); the rest takes the checked step after it.
        let safe_bits = nbits.saturating_sub(64);
        while base + (used as usize) < nbits {
            // Away from the ends: a bit buffer refilled without branches (its bits past the
            // valid count are the next byte's, so OR-ing the reload over them is exact),
            // then up to four table lookups, each one or two codes of at most 12 bits
            // together, or one code of 13 to 24 bits through the second level (then the
            // buffer is refilled: the long codes of noisy float samples' low halves).
            let pos = base + used as usize;
            if pos < safe_bits && k + 8 <= n {
                let load = |p: usize| -> u64 {
                    buf.get(p..p + 8)
                        .and_then(|b| b.try_into().ok())
                        .map_or(0, u64::from_be_bytes)
                };
                // `have` bits of `bits` are valid (at most 63, so the reload's shift is in
                // range); the next byte to load is `p`; the bit position is `8 p - have`.
                let mut p = pos >> 3;
                let mut bits = load(p) << (pos & 7);
                p += 7;
                let mut have = 56 - (pos & 7) as u32;
                'fast: while p * 8 - (have as usize) < safe_bits && k + 8 <= n {
                    bits |= load(p) >> have;
                    p += ((63 - have) >> 3) as usize;
                    have |= 56;
                    for _ in 0..4 {
                        let top = (bits >> (64 - FIRST_BITS)) as usize;
                        let e = self.fast[top];
                        if e >> 48 == 0 {
                            out[k] = e as u16;
                            out[k + 1] = (e >> 16) as u16;
                            k += ((e >> 40) & 3) as usize;
                            let len = ((e >> 32) & 0xff) as u32;
                            bits <<= len;
                            have -= len;
                            continue;
                        }
                        // A code of 13 to 24 bits (not the run code): its second-level
                        // entry, with the 24 bits it may need in the buffer.
                        if have < TWO_LEVEL_BITS {
                            continue 'fast;
                        }
                        let f = self.first[top];
                        if f & 0x80 == 0 {
                            break 'fast;
                        }
                        let at = (f >> 8) as usize
                            + ((bits << FIRST_BITS) >> (64 - (f & 0x7f))) as usize;
                        let e = self.second[at];
                        let len = e & 0xff;
                        if len == 0 || len == SCAN || e >> 8 == rlc {
                            break 'fast;
                        }
                        out[k] = (e >> 8) as u16;
                        k += 1;
                        bits <<= len;
                        have -= len;
                        // Refilled before the next code (at most 36 bits of short codes
                        // and this one's 24 were in the buffer's 56).
                        continue 'fast;
                    }
                }
                base = p * 8 - have as usize;
                used = 0;
                w = window(base);
            }
            if base + (used as usize) >= nbits {
                break;
            }
            if used > 32 {
                base += used as usize;
                used = 0;
                w = window(base);
            }
            // At least 25 bits of the data's: a whole code of up to 24 bits.
            let cur = w << used;
            let top = (cur >> (64 - FIRST_BITS)) as usize;
            let e = self.first[top];
            let e = if e & 0x80 == 0 {
                e
            } else {
                let bits = e & 0x7f;
                let at = (e >> 8) as usize + ((cur << FIRST_BITS) >> (64 - bits)) as usize;
                self.second[at]
            };
            let (symbol, len) = match e & 0xff {
                0 => return Err("PIZ Huffman code invalid"),
                SCAN => {
                    let at = base + used as usize;
                    let (a, b) = (window(at), window(at + 1));
                    let found = self.scan.iter().find(|&&(code, l, _)| {
                        // Up to 57 bits from `a`; a 58-bit code reads its last 57 from `b`.
                        let bits = if l <= 57 {
                            a >> (64 - l)
                        } else {
                            (b >> (64 - (l - 1))) | ((a >> 63) << (l - 1))
                        };
                        bits == code
                    });
                    let &(_, l, s) = found.ok_or("PIZ Huffman code invalid")?;
                    (s, l)
                }
                l => (e >> 8, l),
            };
            if len > 32 {
                base += (used + len) as usize;
                used = 0;
                w = window(base);
            } else {
                used += len;
            }
            if base + used as usize > nbits {
                return Err("PIZ Huffman code past the end of the data");
            }
            if symbol == rlc {
                base += used as usize;
                if base + 8 > nbits {
                    return Err("PIZ Huffman run past the end of the data");
                }
                w = window(base);
                used = 8;
                let repeat = (w >> 56) as usize;
                if k == 0 {
                    return Err("PIZ Huffman run before any value");
                }
                if k + repeat > n {
                    return Err("PIZ Huffman data longer than the block");
                }
                let last = out[k - 1];
                out[k..k + repeat].fill(last);
                k += repeat;
            } else {
                let slot = out
                    .get_mut(k)
                    .ok_or("PIZ Huffman data longer than the block")?;
                *slot = symbol as u16;
                k += 1;
            }
        }
        if k != n {
            return Err("PIZ Huffman data shorter than the block");
        }
        Ok(out)
    }
}

/// Undoes the wavelet transform of one plane: the values `half + words * (x + width * y)`
/// of `plane`, `width` by `lines`; `small`: every value is below 2^14 (the transform then
/// used plain arithmetic, else arithmetic modulo 2^16).
fn undo_wavelet(
    plane: &mut [u16],
    half: usize,
    words: usize,
    width: usize,
    lines: usize,
    small: bool,
) {
    if small {
        undo_wavelet_with::<true>(plane, half, words, width, lines);
    } else {
        undo_wavelet_with::<false>(plane, half, words, width, lines);
    }
}

/// [`pair_14`] (`SMALL`: every value below 2^14) or [`pair_16`].
#[inline(always)]
fn pair<const SMALL: bool>(l: u16, h: u16) -> (u16, u16) {
    if SMALL { pair_14(l, h) } else { pair_16(l, h) }
}

#[inline(always)]
fn pair_14(l: u16, h: u16) -> (u16, u16) {
    let h = i32::from(h as i16);
    let a = i32::from(l as i16) + (h & 1) + (h >> 1);
    (a as u16, (a - h) as u16)
}

#[inline(always)]
fn pair_16(l: u16, h: u16) -> (u16, u16) {
    const OFFSET: i32 = 1 << 15;
    let (m, d) = (i32::from(l), i32::from(h));
    let b = (m - (d >> 1)) & 0xffff;
    let a = (d + b - OFFSET) & 0xffff;
    (a as u16, b as u16)
}

/// The finest level (step 1) of [`undo_wavelet_with`] on a plane of `width` by `lines`
/// samples: each 2x2 square's columns, then its rows; a last odd column's pairs vertically,
/// a last odd row's horizontally.
#[inline(always)]
fn finest_level<const SMALL: bool>(plane: &mut [u16], width: usize) {
    let pair = pair::<SMALL>;
    let mut rows = plane.chunks_exact_mut(2 * width);
    for two in &mut rows {
        let (top, bottom) = two.split_at_mut(width);
        let done = rows_sse2::<SMALL>(top, bottom);
        let (t2, t_odd) = top[done..].as_chunks_mut::<2>();
        let (b2, b_odd) = bottom[done..].as_chunks_mut::<2>();
        for (t, b) in t2.iter_mut().zip(b2.iter_mut()) {
            let (c, up) = pair(t[0], b[0]);
            let (right, up_right) = pair(t[1], b[1]);
            let (c, right) = pair(c, right);
            let (up, up_right) = pair(up, up_right);
            *t = [c, right];
            *b = [up, up_right];
        }
        if let ([t], [b]) = (t_odd, b_odd) {
            (*t, *b) = pair(*t, *b);
        }
    }
    let last = rows.into_remainder();
    if last.len() == width {
        for t in last.as_chunks_mut::<2>().0 {
            let (c, right) = pair(t[0], t[1]);
            *t = [c, right];
        }
    }
}

/// The leading multiple of 16 samples of two rows of [`finest_level`], eight lanes at a time
/// (SSE2, on every x86-64 CPU); how many it did.
fn rows_sse2<const SMALL: bool>(top: &mut [u16], bottom: &mut [u16]) -> usize {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        // SAFETY: SSE2 is enabled for the whole build (as on every x86-64 target).
        #[allow(unsafe_code)]
        unsafe {
            sse2::rows::<SMALL>(top, bottom)
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        let _ = (top, bottom);
        0
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
mod sse2 {
    use std::arch::x86_64::{
        __m128i, _mm_add_epi16, _mm_and_si128, _mm_packs_epi32, _mm_set1_epi16, _mm_slli_epi32,
        _mm_srai_epi16, _mm_srai_epi32, _mm_srli_epi16, _mm_sub_epi16, _mm_unpackhi_epi16,
        _mm_unpacklo_epi16, _mm_xor_si128,
    };

    /// [`super::pair_14`] (`SMALL`) or [`super::pair_16`] in eight lanes: the same
    /// arithmetic modulo 2^16.
    #[target_feature(enable = "sse2")]
    fn pair<const SMALL: bool>(l: __m128i, h: __m128i) -> (__m128i, __m128i) {
        if SMALL {
            // a = l + (h & 1) + (h >> 1) (h signed), b = a - h.
            let a = _mm_add_epi16(
                _mm_add_epi16(l, _mm_and_si128(h, _mm_set1_epi16(1))),
                _mm_srai_epi16::<1>(h),
            );
            (a, _mm_sub_epi16(a, h))
        } else {
            // b = l - (h >> 1) (h unsigned), a = h + b - 2^15.
            let b = _mm_sub_epi16(l, _mm_srli_epi16::<1>(h));
            let a = _mm_xor_si128(_mm_add_epi16(h, b), _mm_set1_epi16(i16::MIN));
            (a, b)
        }
    }

    /// The even and the odd lanes of sixteen 16-bit values (`lo`, then `hi`).
    #[target_feature(enable = "sse2")]
    fn split(lo: __m128i, hi: __m128i) -> (__m128i, __m128i) {
        // Each 32-bit lane's low half sign-extended (the signed pack then keeps it whole),
        // and its high half.
        let even = |v| _mm_srai_epi32::<16>(_mm_slli_epi32::<16>(v));
        let odd = |v| _mm_srai_epi32::<16>(v);
        (
            _mm_packs_epi32(even(lo), even(hi)),
            _mm_packs_epi32(odd(lo), odd(hi)),
        )
    }

    /// [`super::rows_sse2`].
    #[target_feature(enable = "sse2")]
    pub(super) fn rows<const SMALL: bool>(top: &mut [u16], bottom: &mut [u16]) -> usize {
        let (t16, _) = top.as_chunks_mut::<16>();
        let (b16, _) = bottom.as_chunks_mut::<16>();
        let mut done = 0;
        for (t, b) in t16.iter_mut().zip(b16.iter_mut()) {
            let [t0, t1]: [__m128i; 2] = bytemuck::cast(*t);
            let [b0, b1]: [__m128i; 2] = bytemuck::cast(*b);
            // Each column's pair, then each row's pair of columns.
            let (c0, u0) = pair::<SMALL>(t0, b0);
            let (c1, u1) = pair::<SMALL>(t1, b1);
            let (ce, co) = split(c0, c1);
            let (ue, uo) = split(u0, u1);
            let (ce, co) = pair::<SMALL>(ce, co);
            let (ue, uo) = pair::<SMALL>(ue, uo);
            let join = |e, o| bytemuck::cast([_mm_unpacklo_epi16(e, o), _mm_unpackhi_epi16(e, o)]);
            *t = join(ce, co);
            *b = join(ue, uo);
            done += 16;
        }
        done
    }
}

#[inline(always)]
fn undo_wavelet_with<const SMALL: bool>(
    plane: &mut [u16],
    half: usize,
    words: usize,
    width: usize,
    lines: usize,
) {
    let pair = pair::<SMALL>;
    let (ox, oy) = (words, words * width);
    let n = width.min(lines);
    if n < 2 {
        return;
    }
    // The coarsest level's step: the largest power of two at most n.
    let mut p2 = 1usize << (usize::BITS - 1 - n.leading_zeros());
    let mut p = p2 >> 1;
    while p >= 1 {
        if p == 1 && words == 1 {
            // The finest level of a plane of one word per sample (three quarters of the
            // work): rows in pairs, pixels in pairs, sixteen samples at a time with SSE2.
            finest_level::<SMALL>(&mut plane[..width * lines], width);
            break;
        }
        let (x1, y1, x2, y2) = (ox * p, oy * p, ox * p2, oy * p2);
        let mut y = half;
        let y_end = half + oy * (lines - p2);
        while y <= y_end {
            let mut x = y;
            let x_end = y + ox * (width - p2);
            while x <= x_end {
                let (t, r) = (x + y1, x + x1);
                let tr = t + x1;
                let (c, top) = pair(plane[x], plane[t]);
                let (right, top_right) = pair(plane[r], plane[tr]);
                let (c, right) = pair(c, right);
                let (top, top_right) = pair(top, top_right);
                plane[x] = c;
                plane[t] = top;
                plane[r] = right;
                plane[tr] = top_right;
                x += x2;
            }
            if width & p != 0 {
                let t = x + y1;
                let (c, top) = pair(plane[x], plane[t]);
                plane[x] = c;
                plane[t] = top;
            }
            y += y2;
        }
        if lines & p != 0 {
            let mut x = y;
            let x_end = y + ox * (width - p2);
            while x <= x_end {
                let r = x + x1;
                let (c, right) = pair(plane[x], plane[r]);
                plane[x] = c;
                plane[r] = right;
                x += x2;
            }
        }
        p2 = p;
        p >>= 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `fast` table as the first level says it should be, entry by entry (the table's
    /// definition): `SLOW` unless the entry's code is short and not the run code; then that
    /// code, paired (in `pairs` tables) with the short code that its remaining bits start
    /// where both fit in the 12 bits.
    fn fast_from_first(first: &[u32], rlc: u32, pairs: bool) -> Vec<u64> {
        let short = |e: u32| e & 0x80 == 0 && e & 0xff != 0 && e >> 8 != rlc;
        (0..first.len())
            .map(|i| {
                let a = first[i];
                if !short(a) {
                    return SLOW;
                }
                let la = a & 0xff;
                let one = u64::from(a >> 8) | u64::from(la) << 32 | 1 << 40;
                let b = first[(i << la) & (first.len() - 1)];
                let lb = b & 0xff;
                if !pairs || la >= FIRST_BITS || !short(b) || la + lb > FIRST_BITS {
                    return one;
                }
                u64::from(a >> 8) | u64::from(b >> 8) << 16 | u64::from(la + lb) << 32 | 2 << 40
            })
            .collect()
    }

    /// The `fast` table built code by code equals the one its definition gives from the
    /// first level, for complete code tables and for damaged ones (lengths drawn at random,
    /// so that codes overlap, the run code among them), with and without pairs.
    #[test]
    fn fast_entries_follow_the_first_level() {
        let mut rng = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut built = [0usize; 2];
        for round in 0..3000 {
            let symbols = 2 + (rng() % 300) as usize;
            let max_len = 1 + rng() % if round % 3 == 0 { 12 } else { 20 };
            // Complete tables in a third of the rounds: a Huffman code of random weights.
            let lengths: Vec<u8> = if round % 3 == 1 {
                let w: Vec<u64> = (0..symbols).map(|_| 1 + rng() % 1000).collect();
                huffman_lengths(&w)
            } else {
                (0..symbols)
                    .map(|_| {
                        if rng().is_multiple_of(4) {
                            0
                        } else {
                            1 + (rng() % max_len) as u8
                        }
                    })
                    .collect()
            };
            let coded: Vec<(u32, u8)> = lengths
                .iter()
                .enumerate()
                .filter(|&(_, &l)| l > 0)
                .map(|(s, &l)| (s as u32, l))
                .collect();
            let mut per_length = [0u64; 59];
            for &(_, l) in &coded {
                per_length[usize::from(l)] += 1;
            }
            let rlc = (rng() % symbols as u64) as u32;
            for pairs in [false, true] {
                if let Ok(t) = Table::new(&coded, &per_length, rlc, pairs) {
                    built[usize::from(pairs)] += 1;
                    assert_eq!(
                        t.fast,
                        fast_from_first(&t.first, rlc, pairs),
                        "round {round}, pairs {pairs}, lengths {lengths:?}, rlc {rlc}"
                    );
                }
            }
        }
        // Over a third of the tables were built (the complete ones, and damaged ones whose
        // codes fit their lengths), with and without pairs.
        assert!(built.iter().all(|&n| n > 1000), "{built:?}");
    }

    /// Code lengths of a Huffman code for `weights` (at most 58 bits for any weights here).
    fn huffman_lengths(weights: &[u64]) -> Vec<u8> {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let n = weights.len();
        let mut parent = vec![usize::MAX; 2 * n];
        let mut heap: BinaryHeap<_> = weights
            .iter()
            .enumerate()
            .map(|(i, &w)| Reverse((w, i)))
            .collect();
        let mut next = n;
        while heap.len() > 1 {
            let (Some(Reverse((wa, a))), Some(Reverse((wb, b)))) = (heap.pop(), heap.pop()) else {
                break;
            };
            parent[a] = next;
            parent[b] = next;
            heap.push(Reverse((wa + wb, next)));
            next += 1;
        }
        (0..n)
            .map(|mut i| {
                let mut depth = 0u8;
                while parent[i] != usize::MAX {
                    i = parent[i];
                    depth += 1;
                }
                depth
            })
            .collect()
    }

    /// The finest level (sixteen samples at a time where the CPU allows) equals the
    /// transform's 2x2 step written one square at a time (columns, then rows, as
    /// `ImfWav.cpp`'s `wdec14` / `wdec16` order them), for both arithmetics, on planes of
    /// every width up to 40 and 1 to 5 lines.
    #[test]
    fn the_finest_level_is_the_2x2_step() {
        let mut rng = crate::xorshift(0x2545_f491_4f6c_dd1d);
        let mut next = || rng() as u16;
        for small in [true, false] {
            let pair: fn(u16, u16) -> (u16, u16) = if small { pair_14 } else { pair_16 };
            for width in 1..=40 {
                for lines in 1..=5 {
                    let plane: Vec<u16> = (0..width * lines)
                        .map(|_| if small { next() >> 2 } else { next() })
                        .collect();
                    let mut want = plane.clone();
                    let at = |x: usize, y: usize| x + width * y;
                    for y in (0..lines - lines % 2).step_by(2) {
                        for x in (0..width - width % 2).step_by(2) {
                            let (c, up) = pair(want[at(x, y)], want[at(x, y + 1)]);
                            let (r, ur) = pair(want[at(x + 1, y)], want[at(x + 1, y + 1)]);
                            let (c, r) = pair(c, r);
                            let (up, ur) = pair(up, ur);
                            want[at(x, y)] = c;
                            want[at(x + 1, y)] = r;
                            want[at(x, y + 1)] = up;
                            want[at(x + 1, y + 1)] = ur;
                        }
                        if width % 2 == 1 {
                            let x = width - 1;
                            (want[at(x, y)], want[at(x, y + 1)]) =
                                pair(want[at(x, y)], want[at(x, y + 1)]);
                        }
                    }
                    if lines % 2 == 1 {
                        let y = lines - 1;
                        for x in (0..width - width % 2).step_by(2) {
                            (want[at(x, y)], want[at(x + 1, y)]) =
                                pair(want[at(x, y)], want[at(x + 1, y)]);
                        }
                    }
                    let mut got = plane;
                    if small {
                        finest_level::<true>(&mut got, width);
                    } else {
                        finest_level::<false>(&mut got, width);
                    }
                    assert_eq!(got, want, "small {small}, {width} x {lines}");
                }
            }
        }
    }
}
