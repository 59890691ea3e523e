//! Counter-based random numbers: every number is a hash of (seed, pixel, sample, dimension),
//! so an image for a given seed does not depend on how pixels are spread over threads.
//!
//! The hash is SplitMix64's finaliser (Steele, Lea and Flood 2014), applied to a key built
//! from the seed, pixel and sample index, plus the dimension times the golden-ratio
//! increment, exactly as SplitMix64 advances its state. No state is shared between pixels.

/// SplitMix64's output function: a bijective 64-bit mix.
#[inline]
#[must_use]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

/// A random stream for one (seed, pixel, sample): the `d`-th number drawn is
/// `hash(seed, pixel, sample, d)`, whatever was drawn before by other pixels or threads.
#[derive(Clone, Debug)]
pub struct Rng {
    key: u64,
    dim: u64,
}

impl Rng {
    /// The stream for `seed`, linear pixel index `pixel` and sample index `sample`,
    /// starting at dimension 0.
    #[must_use]
    pub fn new(seed: u64, pixel: u64, sample: u64) -> Self {
        let k = mix64(seed.wrapping_add(GOLDEN));
        let k = mix64(k ^ pixel.wrapping_mul(0xd6e8_feb8_6659_fd93));
        let k = mix64(k ^ sample.wrapping_mul(0xa076_1d64_78bd_642f));
        Rng { key: k, dim: 0 }
    }

    /// The number at dimension `dim` of this stream, without moving it.
    #[inline]
    #[must_use]
    pub fn at(&self, dim: u64) -> u64 {
        mix64(
            self.key
                .wrapping_add(dim.wrapping_add(1).wrapping_mul(GOLDEN)),
        )
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        let v = self.at(self.dim);
        self.dim += 1;
        v
    }

    /// The next uniform number in `[0, 1)` (24 random bits, so exactly representable).
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// An exponentially distributed distance with rate `sigma` (per unit length):
    /// `-ln(1 - u) / sigma` (MDWT Listing 1). `sigma` must be positive.
    #[inline]
    pub fn exponential(&mut self, sigma: f32) -> f32 {
        -(1.0 - self.uniform()).ln() / sigma
    }

    /// How many numbers have been drawn.
    #[must_use]
    pub fn dimension(&self) -> u64 {
        self.dim
    }

    /// Moves the stream to dimension `dim` (what [`Rng::dimension`] said when the stream
    /// was handed on): a stream rebuilt with the same seed, pixel and sample and moved
    /// there draws what the original would have drawn next.
    pub fn set_dimension(&mut self, dim: u64) {
        self.dim = dim;
    }
}
