//! ChaCha8, sixteen blocks at a time with AVX-512 where the CPU has it:
//! the stream of `rand_chacha::ChaCha8Rng`, word for word.
//!
//! Why: the particle filters draw four normals a particle for the
//! prediction and four more for the regularization, eight bytes each, and
//! rand_chacha's block function (AVX2, four blocks at a time, through
//! ppv-lite86) took a sixth of the fusion filter's step (perf). With
//! AVX-512 each of sixteen registers holds one word of sixteen blocks, so
//! the rounds run on all sixteen blocks at once and the rotations are one
//! instruction; a 16 × 16 transpose puts the words back in stream order.
//! Where the CPU lacks AVX-512, this is rand_chacha's generator itself.
//!
//! The consumption of words (`next_u32`, `next_u64`, `fill_bytes`) is
//! rand_core's `BlockRng`, as in rand_chacha, over a buffer of sixteen
//! blocks instead of four. The words come out in stream order either way,
//! so the two generators give the same values for any sequence of calls
//! (`the_stream_is_rand_chachas`).

use rand::{CryptoRng, RngCore, SeedableRng};
use rand_chacha::rand_core::block::{BlockRng, BlockRngCore};
use rand_chacha::ChaCha8Rng;

/// Words in a block, and blocks a generation makes.
const BLOCK_WORDS: usize = 16;
const BLOCKS: usize = 16;
const WORDS: usize = BLOCK_WORDS * BLOCKS;

/// "expand 32-byte k".
const CONSTANTS: [u32; 4] = [0x6170_7865, 0x3320_646e, 0x7962_2d32, 0x6b20_6574];

/// ChaCha8 with a 64-bit block counter and a 64-bit stream id, as
/// rand_chacha lays them out.
#[derive(Clone, Debug)]
pub struct WideChaCha8(Engine);

// One generator a filter: a box would put a pointer in front of every draw.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Engine {
    /// Sixteen blocks at a time (the CPU has AVX-512).
    Wide(BlockRng<Core>),
    /// rand_chacha's four.
    Narrow(ChaCha8Rng),
}

#[derive(Clone, Debug)]
struct Core {
    key: [u32; 8],
    stream: u64,
    /// The first block of the next generation.
    block: u64,
}

/// Sixteen blocks of output, in stream order.
#[derive(Clone, Debug)]
struct Blocks([u32; WORDS]);

impl Default for Blocks {
    fn default() -> Self {
        Self([0; WORDS])
    }
}

impl AsRef<[u32]> for Blocks {
    fn as_ref(&self) -> &[u32] {
        &self.0
    }
}

impl AsMut<[u32]> for Blocks {
    fn as_mut(&mut self) -> &mut [u32] {
        &mut self.0
    }
}

impl BlockRngCore for Core {
    type Item = u32;
    type Results = Blocks;

    #[inline]
    fn generate(&mut self, results: &mut Blocks) {
        let state = self.state();
        self.block = self.block.wrapping_add(BLOCKS as u64);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a `Core` is made only where the CPU has AVX-512 (`with_blocks`).
        unsafe {
            avx512::blocks(&state, &mut results.0)
        };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("a wide generator is made only where the CPU has AVX-512 ({state:?})");
    }
}

impl Core {
    /// The sixteen words of the first block's input.
    fn state(&self) -> [u32; 16] {
        let mut s = [0; 16];
        s[..4].copy_from_slice(&CONSTANTS);
        s[4..12].copy_from_slice(&self.key);
        s[12] = self.block as u32;
        s[13] = (self.block >> 32) as u32;
        s[14] = self.stream as u32;
        s[15] = (self.stream >> 32) as u32;
        s
    }
}

impl WideChaCha8 {
    /// The generator at word `word` of stream `stream` of `seed`, as
    /// rand_chacha's `from_seed`, `set_stream` and `set_word_pos` place it.
    pub fn at(seed: [u8; 32], stream: u64, word: u128) -> Self {
        Self::with_blocks(seed, stream, word, has_avx512())
    }

    fn with_blocks(seed: [u8; 32], stream: u64, word: u128, avx512: bool) -> Self {
        // The counter is 64 bits of blocks: word positions wrap at 2^68.
        let word = word % (1u128 << 68);
        if !avx512 {
            let mut rng = ChaCha8Rng::from_seed(seed);
            rng.set_stream(stream);
            rng.set_word_pos(word);
            return Self(Engine::Narrow(rng));
        }
        let key = std::array::from_fn(|i| {
            u32::from_le_bytes(seed[4 * i..4 * i + 4].try_into().expect("four bytes"))
        });
        let mut rng = BlockRng::new(Core {
            key,
            stream,
            block: (word / BLOCK_WORDS as u128) as u64,
        });
        rng.generate_and_set((word % BLOCK_WORDS as u128) as usize);
        Self(Engine::Wide(rng))
    }

    /// The generator where `rng` stands: the same words from here on.
    pub fn from_rand_chacha(rng: &ChaCha8Rng) -> Self {
        Self::at(rng.get_seed(), rng.get_stream(), rng.get_word_pos())
    }
}

impl RngCore for WideChaCha8 {
    #[inline]
    fn next_u32(&mut self) -> u32 {
        match &mut self.0 {
            Engine::Wide(rng) => rng.next_u32(),
            Engine::Narrow(rng) => rng.next_u32(),
        }
    }

    #[inline]
    fn next_u64(&mut self) -> u64 {
        match &mut self.0 {
            Engine::Wide(rng) => rng.next_u64(),
            Engine::Narrow(rng) => rng.next_u64(),
        }
    }

    #[inline]
    fn fill_bytes(&mut self, dest: &mut [u8]) {
        match &mut self.0 {
            Engine::Wide(rng) => rng.fill_bytes(dest),
            Engine::Narrow(rng) => rng.fill_bytes(dest),
        }
    }
}

impl SeedableRng for WideChaCha8 {
    type Seed = [u8; 32];

    fn from_seed(seed: [u8; 32]) -> Self {
        Self::at(seed, 0, 0)
    }
}

impl CryptoRng for WideChaCha8 {}

fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{BLOCK_WORDS, WORDS};
    use std::arch::x86_64::*;

    /// Sixteen blocks from `state` (the first block's input; the others
    /// count on from it), in stream order.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn blocks(state: &[u32; 16], out: &mut [u32; WORDS]) {
        let word = |i: usize| _mm512_set1_epi32(state[i] as i32);
        // Lane j is block `counter + j`, the counter 64 bits wide.
        let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let low = _mm512_add_epi32(word(12), lanes);
        let carried = _mm512_cmplt_epu32_mask(low, word(12));
        let high = _mm512_mask_add_epi32(word(13), carried, word(13), _mm512_set1_epi32(1));
        let mut input = [_mm512_setzero_si512(); 16];
        for (i, v) in input.iter_mut().enumerate() {
            *v = match i {
                12 => low,
                13 => high,
                _ => word(i),
            };
        }
        let mut x = input;
        for _ in 0..4 {
            quarter_round(&mut x, 0, 4, 8, 12);
            quarter_round(&mut x, 1, 5, 9, 13);
            quarter_round(&mut x, 2, 6, 10, 14);
            quarter_round(&mut x, 3, 7, 11, 15);
            quarter_round(&mut x, 0, 5, 10, 15);
            quarter_round(&mut x, 1, 6, 11, 12);
            quarter_round(&mut x, 2, 7, 8, 13);
            quarter_round(&mut x, 3, 4, 9, 14);
        }
        for (v, i) in x.iter_mut().zip(input) {
            *v = _mm512_add_epi32(*v, i);
        }
        let blocks = transpose(x);
        for (j, b) in blocks.into_iter().enumerate() {
            // SAFETY: block j's sixteen words lie within `out`.
            unsafe { _mm512_storeu_epi32(out.as_mut_ptr().add(BLOCK_WORDS * j).cast(), b) };
        }
    }

    #[target_feature(enable = "avx512f")]
    #[inline]
    fn quarter_round(x: &mut [__m512i; 16], a: usize, b: usize, c: usize, d: usize) {
        x[a] = _mm512_add_epi32(x[a], x[b]);
        x[d] = _mm512_rol_epi32::<16>(_mm512_xor_si512(x[d], x[a]));
        x[c] = _mm512_add_epi32(x[c], x[d]);
        x[b] = _mm512_rol_epi32::<12>(_mm512_xor_si512(x[b], x[c]));
        x[a] = _mm512_add_epi32(x[a], x[b]);
        x[d] = _mm512_rol_epi32::<8>(_mm512_xor_si512(x[d], x[a]));
        x[c] = _mm512_add_epi32(x[c], x[d]);
        x[b] = _mm512_rol_epi32::<7>(_mm512_xor_si512(x[b], x[c]));
    }

    /// Register i holds word i of the sixteen blocks; returns register j
    /// holding block j's sixteen words. Within 128-bit lanes first (rows
    /// in fours), then the 4 × 4 lanes.
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn transpose(x: [__m512i; 16]) -> [__m512i; 16] {
        // Lane L of y[2i] holds words 4L, 4L + 1 of rows 2i, 2i + 1
        // interleaved; y[2i + 1] words 4L + 2, 4L + 3.
        let mut y = [_mm512_setzero_si512(); 16];
        for i in 0..8 {
            y[2 * i] = _mm512_unpacklo_epi32(x[2 * i], x[2 * i + 1]);
            y[2 * i + 1] = _mm512_unpackhi_epi32(x[2 * i], x[2 * i + 1]);
        }
        // Lane L of z[4g + k]: column 4L + k of rows 4g .. 4g + 3.
        let mut z = [_mm512_setzero_si512(); 16];
        for g in 0..4 {
            let r = 4 * g;
            z[r] = _mm512_unpacklo_epi64(y[r], y[r + 2]);
            z[r + 1] = _mm512_unpackhi_epi64(y[r], y[r + 2]);
            z[r + 2] = _mm512_unpacklo_epi64(y[r + 1], y[r + 3]);
            z[r + 3] = _mm512_unpackhi_epi64(y[r + 1], y[r + 3]);
        }
        // Column 4L + k is lane L of z[k], z[4 + k], z[8 + k], z[12 + k]:
        // a 4 × 4 transpose of 128-bit lanes.
        let mut out = [_mm512_setzero_si512(); 16];
        for k in 0..4 {
            let (a, b, c, d) = (z[k], z[4 + k], z[8 + k], z[12 + k]);
            let p = _mm512_shuffle_i32x4::<0x44>(a, b); // a0 a1 b0 b1
            let q = _mm512_shuffle_i32x4::<0xEE>(a, b); // a2 a3 b2 b3
            let r = _mm512_shuffle_i32x4::<0x44>(c, d); // c0 c1 d0 d1
            let s = _mm512_shuffle_i32x4::<0xEE>(c, d); // c2 c3 d2 d3
            out[k] = _mm512_shuffle_i32x4::<0x88>(p, r); // a0 b0 c0 d0
            out[4 + k] = _mm512_shuffle_i32x4::<0xDD>(p, r); // a1 b1 c1 d1
            out[8 + k] = _mm512_shuffle_i32x4::<0x88>(q, s);
            out[12 + k] = _mm512_shuffle_i32x4::<0xDD>(q, s);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    /// Both ways of making blocks, wherever the CPU allows the fast one.
    fn both(seed: [u8; 32], stream: u64, word: u128) -> Vec<WideChaCha8> {
        let mut out = vec![WideChaCha8::with_blocks(seed, stream, word, false)];
        if has_avx512() {
            out.push(WideChaCha8::with_blocks(seed, stream, word, true));
        }
        out
    }

    fn theirs(seed: [u8; 32], stream: u64, word: u128) -> ChaCha8Rng {
        let mut rng = ChaCha8Rng::from_seed(seed);
        rng.set_stream(stream);
        rng.set_word_pos(word);
        rng
    }

    /// Any sequence of calls gives rand_chacha's values: words, pairs of
    /// words across the buffer's end, bytes of every length, at any
    /// position, on any stream, and across the counter's low word.
    #[test]
    fn the_stream_is_rand_chachas() {
        let mut pick = ChaCha8Rng::seed_from_u64(11);
        let starts = [
            0u128,
            1,
            15,
            16,
            255,
            256,
            1023,
            (1 << 36) - 40,
            (1 << 68) - 50,
        ];
        for trial in 0..60 {
            let seed: [u8; 32] = pick.random();
            let stream = if trial % 3 == 0 { 0 } else { pick.random() };
            let word = starts[trial % starts.len()] + pick.random_range(0..3);
            for mut ours in both(seed, stream, word) {
                let mut them = theirs(seed, stream, word);
                for _ in 0..600 {
                    match pick.random_range(0..4) {
                        0 => assert_eq!(ours.next_u32(), them.next_u32()),
                        1 => assert_eq!(ours.next_u64(), them.next_u64()),
                        2 => {
                            let n = pick.random_range(0..100);
                            let (mut a, mut b) = (vec![0u8; n], vec![0u8; n]);
                            ours.fill_bytes(&mut a);
                            them.fill_bytes(&mut b);
                            assert_eq!(a, b);
                        }
                        _ => assert_eq!(
                            ours.sample::<f64, _>(rand_distr::StandardNormal).to_bits(),
                            them.sample::<f64, _>(rand_distr::StandardNormal).to_bits()
                        ),
                    }
                }
            }
        }
    }

    /// Built from a rand_chacha generator part-way through its stream, it
    /// goes on where that one stands.
    #[test]
    fn it_goes_on_where_rand_chacha_stands() {
        let mut them = ChaCha8Rng::seed_from_u64(5);
        them.set_stream(9);
        for _ in 0..37 {
            them.next_u32();
        }
        let mut ours = WideChaCha8::from_rand_chacha(&them);
        for _ in 0..2000 {
            assert_eq!(ours.next_u64(), them.next_u64());
        }
    }

    /// The counter carries from its low word to its high one between two
    /// lanes of one generation, as rand_chacha's does.
    #[test]
    fn the_counter_carries_within_a_generation() {
        let word = ((1u128 << 32) - 5) * BLOCK_WORDS as u128;
        for mut ours in both([7; 32], 3, word) {
            let mut them = theirs([7; 32], 3, word);
            for _ in 0..(2 * WORDS) {
                assert_eq!(ours.next_u32(), them.next_u32());
            }
        }
    }
}
