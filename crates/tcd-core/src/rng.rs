//! Noise for the samplers: injected by the caller, or drawn from a named portable generator.
//! The layout and the generator are documented on [`Noise`], which the public API shows.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Stage numbers (the last key word): which model of a call a chain belongs to, so that no two
/// models draw the same stream from one seed.
pub mod stage {
    /// Plain [`crate::sample`], [`crate::repair`] and the short-term stage of
    /// [`crate::cascade`].
    pub const SHORT: u64 = 0;
    /// The long-term stage of [`crate::cascade`].
    pub const LONG: u64 = 1;
    /// [`crate::Generator::sample`]: sample s of sequence b draws its `z_dim` normals z from the
    /// chain (b, s) of this stage, so a seed shared with the diffusion samples of the same windows
    /// gives the generator streams of its own.
    pub const GENERATOR: u64 = 2;
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

/// How the S chains of one sequence share their starting noise x_T: a sampler setting
/// ([`crate::SamplerConfig::noise_coupling`]), applied to seeded and injected noise alike.
///
/// `Centered` replaces chain s's x_T by `((z_s − c) · √(S/(S−1)))` rounded to f32, where `c` is the mean of
/// the S chains' x_T of the sequence (summed in f64 in chain order, then divided by S) and every operation
/// is in f64. Each chain's x_T is still a standard normal vector (z_s − c has covariance (1 − 1/S) I) but
/// the S of a sequence sum to zero, so their samples are negatively correlated: they spread further
/// apart and their mean is less noisy than with independent draws. The per-step noise z of DDPM / DDIM
/// (η > 0) is left as drawn, and a call with one chain per sequence (S = 1) is not coupled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NoiseCoupling {
    /// Every chain's x_T as drawn (or injected): independent samples, the paper's.
    #[default]
    Independent,
    /// The S chains' x_T of each sequence centred on their mean and rescaled to unit variance.
    Centered,
}

impl NoiseCoupling {
    /// Every coupling's name, the default (`independent`) first.
    pub const NAMES: [&'static str; 2] = ["independent", "centered"];

    /// `independent` | `centered`.
    pub fn as_str(self) -> &'static str {
        match self {
            NoiseCoupling::Independent => "independent",
            NoiseCoupling::Centered => "centered",
        }
    }
}

impl std::str::FromStr for NoiseCoupling {
    type Err = crate::Error;
    fn from_str(s: &str) -> crate::Result<Self> {
        match s {
            "independent" => Ok(NoiseCoupling::Independent),
            "centered" => Ok(NoiseCoupling::Centered),
            other => Err(crate::Error::invalid_input(
                "noise_coupling",
                "\"independent\" or \"centered\"",
                format!("{other:?}"),
            )),
        }
    }
}

/// The per-sequence centres of a call's x_T under [`NoiseCoupling::Centered`]: for each sequence b the mean
/// `c_b` of its S chains' block 0 (K·L values, f64), and the scale √(S/(S−1)).
pub(crate) struct Centres {
    means: Vec<f64>,
    block_len: usize,
    scale: f64,
}

impl Centres {
    /// The centres of a call's noise (`data` of an injected call already length-checked); `None` where
    /// nothing is coupled (`Independent`, or S = 1). A seeded call draws each chain's x_T once more here:
    /// S · B · K·L normals, what its chains draw for x_T themselves.
    pub(crate) fn new(
        coupling: NoiseCoupling,
        noise: Noise<'_>,
        stage: u64,
        num_samples: usize,
        num_blocks: usize,
        batch: usize,
        block_len: usize,
    ) -> Option<Self> {
        if coupling == NoiseCoupling::Independent || num_samples < 2 {
            return None;
        }
        let mut means = vec![0.0f64; batch * block_len];
        let mut x_t = vec![0.0f32; block_len];
        for (b, mean) in means.chunks_exact_mut(block_len).enumerate() {
            for s in 0..num_samples {
                ChainNoise::new(noise, stage, s, b, num_blocks, batch, None).fill(0, &mut x_t);
                for (m, &v) in mean.iter_mut().zip(&x_t) {
                    *m += v as f64;
                }
            }
            for m in mean.iter_mut() {
                *m /= num_samples as f64;
            }
        }
        Some(Centres {
            means,
            block_len,
            scale: (num_samples as f64 / (num_samples - 1) as f64).sqrt(),
        })
    }

    /// The centre of sequence `b` and the scale.
    pub(crate) fn of(&self, b: usize) -> (&[f64], f64) {
        (
            &self.means[b * self.block_len..][..self.block_len],
            self.scale,
        )
    }
}

/// The noise of one chain: its source, and the centre its x_T is moved off under
/// [`NoiseCoupling::Centered`].
pub(crate) struct ChainNoise<'a> {
    source: ChainSource<'a>,
    centre: Option<(&'a [f64], f64)>,
}

/// Where one chain's blocks come from.
enum ChainSource<'a> {
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
    /// The noise of chain (sample, sequence) of a call; `data` already length-checked; `centre`: the
    /// sequence's [`Centres::of`] where the call is coupled.
    pub(crate) fn new(
        noise: Noise<'a>,
        stage: u64,
        sample: usize,
        sequence: usize,
        num_blocks: usize,
        batch: usize,
        centre: Option<(&'a [f64], f64)>,
    ) -> Self {
        let source = match noise {
            Noise::Injected(data) => ChainSource::Injected {
                data,
                sample,
                sequence,
                num_blocks,
                batch,
            },
            Noise::Seeded { seed, sequences } => ChainSource::Seeded(Box::new(chain_rng(
                seed,
                sequences.id(sequence),
                sample as u64,
                stage,
            ))),
        };
        ChainNoise { source, centre }
    }

    /// Writes block `j` (called with j = 0, 1, 2, ... in order) into `out` (K·L values): block 0 moved off
    /// the sequence's centre where the call is coupled.
    pub(crate) fn fill(&mut self, j: usize, out: &mut [f32]) {
        match &mut self.source {
            ChainSource::Injected {
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
            ChainSource::Seeded(rng) => fill_standard_normal(rng, out),
        }
        if let (0, Some((centre, scale))) = (j, self.centre) {
            for (v, &c) in out.iter_mut().zip(centre) {
                *v = ((*v as f64 - c) * scale) as f32;
            }
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

    /// Centred x_T: block 0 of chain s is ((z_s − c) · √(S/(S−1))) in f64 with c the chain-order f64 mean of
    /// the sequence's S blocks 0; the S of a sequence sum to (about) zero; later blocks are as drawn.
    #[test]
    fn centred_x_t_follows_its_definition() {
        let (s_n, blocks, batch, len) = (5usize, 3usize, 2usize, 64usize);
        let raw = seeded_noise(4, Sequences::From(0), stage::LONG, s_n, blocks, batch, len);
        let noise = Noise::seeded(4);
        let centres = Centres::new(
            NoiseCoupling::Centered,
            noise,
            stage::LONG,
            s_n,
            blocks,
            batch,
            len,
        )
        .unwrap();
        let block =
            |s: usize, j: usize, b: usize| &raw[((s * blocks + j) * batch + b) * len..][..len];
        let scale = (5.0f64 / 4.0).sqrt();
        for b in 0..batch {
            let mut sum = vec![0.0f64; len];
            for s in 0..s_n {
                let mut chain =
                    ChainNoise::new(noise, stage::LONG, s, b, blocks, batch, Some(centres.of(b)));
                let mut out = vec![0.0f32; len];
                chain.fill(0, &mut out);
                for i in 0..len {
                    let mut c = 0.0f64;
                    for t in 0..s_n {
                        c += block(t, 0, b)[i] as f64;
                    }
                    c /= s_n as f64;
                    assert_eq!(out[i], ((block(s, 0, b)[i] as f64 - c) * scale) as f32);
                    sum[i] += out[i] as f64;
                }
                for j in 1..blocks {
                    chain.fill(j, &mut out);
                    assert_eq!(out, block(s, j, b));
                }
            }
            assert!(sum.iter().all(|v| v.abs() < 1e-5), "{sum:?}");
        }
        let none = |c, s| Centres::new(c, noise, 0, s, blocks, batch, len).is_none();
        assert!(none(NoiseCoupling::Independent, 5) && none(NoiseCoupling::Centered, 1));
        assert_eq!(
            "centered".parse::<NoiseCoupling>().unwrap(),
            NoiseCoupling::Centered
        );
        let e = "antithetic".parse::<NoiseCoupling>().unwrap_err();
        assert!(e.to_string().contains("noise_coupling"), "{e}");
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
