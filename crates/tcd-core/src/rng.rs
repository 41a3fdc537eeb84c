//! Noise for the samplers: injected by the caller, or drawn from a named portable generator.
//! The layout and the generator are documented on [`Noise`], which the public API shows.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Stage numbers (the last key word): which model of a cascade a chain belongs to.
pub mod stage {
    /// Plain [`crate::sample`], [`crate::repair`] and the short-term stage of
    /// [`crate::cascade`].
    pub const SHORT: u64 = 0;
    /// The long-term stage of [`crate::cascade`].
    pub const LONG: u64 = 1;
}

/// Where a sampling call gets its noise.
///
/// # Layout
/// The noise of one call is one f32 array of shape **(S, n + 1, B, K, L)** (S samples, n sampler
/// steps): block 0 of a chain is x_T, block i + 1 the z used at step i (drawn but unused where
/// σ = 0). With S = 1 this is the (n + 1, B, K, L) array of the PyTorch side. The deterministic
/// DPM-Solver++(2M) (`dpmpp2m`) draws no per-step noise: its chains have one block, x_T
/// ([`crate::Plan::num_noise_blocks`]).
///
/// # Generator
/// Seeded noise is **ChaCha8** (`rand_chacha::ChaCha8Rng`, rand_chacha 0.9, stream 0) with the
/// 32-byte key `seed ‖ sequence ‖ sample ‖ stage`, each a little-endian u64, and standard normals
/// from **`rand_distr::StandardNormal`** (rand_distr 0.5 ziggurat on f64 with its libm maths,
/// rounded to f32). One generator per chain (sequence × sample × stage), drawn in block order
/// x_T, z_0, z_1, ..., so results depend neither on the thread count nor on which other
/// sequences are in the batch: [`Sequences`] numbers them (from a first id, to continue a
/// numbering across calls, or one id per sequence, to give each window of a long recording its own
/// stream whatever batch it lands in).
/// [`seeded_noise`] materialises exactly what the seeded path consumes, for parity tests.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Noise<'a> {
    /// Caller-supplied standard normals, shape (S, n + 1, B, K, L).
    Injected(&'a [f32]),
    /// Seeded ChaCha8 streams; sequence b of the call draws stream `sequences.id(b)`.
    Seeded { seed: u64, sequences: Sequences<'a> },
}

impl Noise<'_> {
    /// Seeded noise with sequences numbered from 0.
    pub fn seeded(seed: u64) -> Self {
        Noise::Seeded {
            seed,
            sequences: Sequences::From(0),
        }
    }
}

/// The stream id (the key's `sequence` word) of each sequence of a seeded call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sequences<'a> {
    /// Sequence b is stream `first + b` (wrapping).
    From(u64),
    /// Sequence b is stream `ids[b]`: one id per sequence of the batch.
    Ids(&'a [u64]),
}

impl Sequences<'_> {
    /// The stream of sequence `b` (`Ids` already checked to hold one id per sequence).
    pub fn id(&self, b: usize) -> u64 {
        match *self {
            Sequences::From(first) => first.wrapping_add(b as u64),
            Sequences::Ids(ids) => ids[b],
        }
    }

    /// Checks that `Ids` holds one id per sequence of a batch of `batch`.
    pub(crate) fn check(&self, batch: usize) -> crate::Result<()> {
        match *self {
            Sequences::Ids(ids) if ids.len() != batch => Err(crate::Error::invalid_input(
                "sequences",
                format!("one stream id per sequence ({batch})"),
                format!("{} ids", ids.len()),
            )),
            _ => Ok(()),
        }
    }
}

/// The generator of one chain.
pub fn chain_rng(seed: u64, sequence: u64, sample: u64, stage: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    for (dst, word) in key.chunks_exact_mut(8).zip([seed, sequence, sample, stage]) {
        dst.copy_from_slice(&word.to_le_bytes());
    }
    ChaCha8Rng::from_seed(key)
}

/// Fills `out` with standard normals from `rng`.
pub fn fill_standard_normal(rng: &mut ChaCha8Rng, out: &mut [f32]) {
    for v in out.iter_mut() {
        *v = rng.sample(StandardNormal);
    }
}

/// The seeded noise of a whole call in the injected layout (S, n + 1, B, K·L):
/// `num_blocks` = n + 1, `block_len` = K·L.
pub fn seeded_noise(
    seed: u64,
    sequences: Sequences<'_>,
    stage: u64,
    num_samples: usize,
    num_blocks: usize,
    batch: usize,
    block_len: usize,
) -> Vec<f32> {
    let mut out = vec![0.0f32; num_samples * num_blocks * batch * block_len];
    for s in 0..num_samples {
        for b in 0..batch {
            let mut rng = chain_rng(seed, sequences.id(b), s as u64, stage);
            for j in 0..num_blocks {
                let off = ((s * num_blocks + j) * batch + b) * block_len;
                fill_standard_normal(&mut rng, &mut out[off..off + block_len]);
            }
        }
    }
    out
}

/// The noise source of one chain.
pub(crate) enum ChainNoise<'a> {
    Injected {
        data: &'a [f32],
        sample: usize,
        sequence: usize,
        num_blocks: usize,
        batch: usize,
    },
    Seeded(Box<ChaCha8Rng>),
}

impl<'a> ChainNoise<'a> {
    /// The noise of chain (sample, sequence) of a call; `data` already length-checked.
    pub(crate) fn new(
        noise: Noise<'a>,
        stage: u64,
        sample: usize,
        sequence: usize,
        num_blocks: usize,
        batch: usize,
    ) -> Self {
        match noise {
            Noise::Injected(data) => ChainNoise::Injected {
                data,
                sample,
                sequence,
                num_blocks,
                batch,
            },
            Noise::Seeded { seed, sequences } => ChainNoise::Seeded(Box::new(chain_rng(
                seed,
                sequences.id(sequence),
                sample as u64,
                stage,
            ))),
        }
    }

    /// Writes block `j` (called with j = 0, 1, 2, ... in order) into `out` (K·L values).
    pub(crate) fn fill(&mut self, j: usize, out: &mut [f32]) {
        match self {
            ChainNoise::Injected {
                data,
                sample,
                sequence,
                num_blocks,
                batch,
            } => {
                let n = out.len();
                let off = ((*sample * *num_blocks + j) * *batch + *sequence) * n;
                if let Some(src) = data.get(off..off + n) {
                    out.copy_from_slice(src);
                }
            }
            ChainNoise::Seeded(rng) => fill_standard_normal(rng, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a = seeded_noise(7, Sequences::From(0), stage::SHORT, 2, 3, 2, 5);
        let b = seeded_noise(7, Sequences::From(0), stage::SHORT, 2, 3, 2, 5);
        assert_eq!(a, b);
        let c = seeded_noise(8, Sequences::From(0), stage::SHORT, 2, 3, 2, 5);
        assert_ne!(a, c);
        let d = seeded_noise(7, Sequences::From(0), stage::LONG, 2, 3, 2, 5);
        assert_ne!(a, d);
        // sequence 1 of a batch of 2 == sequence 0 of a batch of 1 with first_sequence 1
        let e = seeded_noise(7, Sequences::From(1), stage::SHORT, 2, 3, 1, 5);
        for s in 0..2 {
            for j in 0..3 {
                let from_a = &a[((s * 3 + j) * 2 + 1) * 5..][..5];
                let from_e = &e[(s * 3 + j) * 5..][..5];
                assert_eq!(from_a, from_e);
            }
        }
        // explicit ids: sequence b draws stream ids[b], whatever its position in the batch
        let f = seeded_noise(7, Sequences::Ids(&[1, 0]), stage::SHORT, 2, 3, 2, 5);
        for s in 0..2 {
            for j in 0..3 {
                let row = |v: &[f32], b: usize| v[((s * 3 + j) * 2 + b) * 5..][..5].to_vec();
                assert_eq!(row(&f, 0), row(&a, 1));
                assert_eq!(row(&f, 1), row(&a, 0));
            }
        }
        assert!(Sequences::Ids(&[1, 2]).check(3).is_err());
        assert!(Sequences::Ids(&[1, 2]).check(2).is_ok());
    }

    #[test]
    fn normals_look_standard() {
        let v = seeded_noise(1, Sequences::From(0), 0, 1, 1, 1, 20_000);
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / v.len() as f64;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "var {var}");
    }
}
