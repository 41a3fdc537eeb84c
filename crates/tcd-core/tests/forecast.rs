//! Cascade and repair on tiny models: short (O = 6, L_s = 8) → long (8 + 4 = 12).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use tcd_core::rng::{seeded_noise, stage};
use tcd_core::{
    cascade, repair, sample, CascadeNoise, Control, Denoiser, ForecastOptions, Noise, Observed, Role,
    SamplerConfig, Sequences,
};

fn models() -> (Denoiser, Denoiser) {
    (
        tiny_model(Role::Short, 6, 2, 31).0,
        tiny_model(Role::Long, 8, 4, 32).0,
    )
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn cascade_shapes_and_invariants() {
    let (short, long) = models();
    let (b, k, o, s) = (2usize, 6usize, 6usize, 3usize);
    let observed = values(b * k * o, 1, 1.0);
    let mut mask = binary_mask(b * k * o, 2, 0.8);
    mask[0] = 0.0;
    let mut observed_nan = observed.clone();
    observed_nan[0] = f32::NAN; // missing entry marked with NaN
    let opts = ForecastOptions {
        num_samples: s,
        sampler: SamplerConfig::ddim(4, 0.5),
    };
    let noise = CascadeNoise::Seeded {
        seed: 4,
        sequences: Sequences::From(0),
    };
    let out = cascade(&short, &long, &observed_nan, &mask, &opts, noise, &Control::default()).unwrap();
    assert_eq!((out.obs_len, out.short_len, out.future_len), (6, 8, 6));
    assert_eq!(out.mean.len(), b * k * 6);
    assert_eq!(out.samples.len(), s * b * k * 6);
    assert_eq!(out.repaired.len(), b * k * o);
    assert_eq!(out.short_mean.len(), b * k * 8);
    assert!(out
        .samples
        .iter()
        .chain(&out.mean)
        .chain(&out.repaired)
        .all(|v| v.is_finite()));
    // observed entries of the repaired observation are exact
    for i in 0..b * k * o {
        if mask[i] == 1.0 {
            assert_eq!(out.repaired[i].to_bits(), observed[i].to_bits());
        }
    }
    // future frames 0..2 (the short model's prediction) are the short mean in every long sample
    for si in 0..s {
        for row in 0..b * k {
            for f in 0..2 {
                let v = out.samples[(si * b * k + row) * 6 + f];
                assert_eq!(v.to_bits(), out.short_mean[row * 8 + 6 + f].to_bits());
            }
        }
    }
    // the remaining future frames differ between samples
    assert_ne!(out.samples[2..6], out.samples[b * k * 6 + 2..b * k * 6 + 6]);
    // mean is the mean of the samples
    for i in 0..b * k * 6 {
        let m: f32 = (0..s)
            .map(|si| out.samples[si * b * k * 6 + i])
            .sum::<f32>()
            / s as f32;
        assert_eq!(m, out.mean[i]);
    }
}

#[test]
fn cascade_short_stage_is_plain_sampling() {
    let (short, long) = models();
    let (b, k, o, s) = (1usize, 6usize, 6usize, 2usize);
    let observed = values(b * k * o, 1, 1.0);
    let mask = vec![1.0f32; b * k * o];
    let opts = ForecastOptions {
        num_samples: s,
        sampler: SamplerConfig::ddpm(),
    };
    let out = cascade(
        &short,
        &long,
        &observed,
        &mask,
        &opts,
        CascadeNoise::Seeded {
            seed: 8,
            sequences: Sequences::From(0),
        },
        &Control::default(),
    )
    .unwrap();
    // rebuild the short stage by hand
    let mut x = vec![0.0f32; k * 8];
    let mut m = vec![0.0f32; k * 8];
    for kk in 0..k {
        x[kk * 8..kk * 8 + 6].copy_from_slice(&observed[kk * 6..kk * 6 + 6]);
        m[kk * 8..kk * 8 + 6].fill(1.0);
    }
    let samples = sample(
        &short,
        Observed::new(&x, &m, 1, 8),
        s,
        &opts.sampler,
        Noise::seeded(8),
        &Control::default(),
    )
    .unwrap();
    for i in 0..k * 8 {
        let want = if m[i] == 1.0 {
            x[i]
        } else {
            (samples[i] + samples[k * 8 + i]) / 2.0
        };
        assert_eq!(out.short_mean[i], want);
    }
}

#[test]
fn cascade_thread_independent_and_injected_equals_seeded() {
    let (short, long) = models();
    let (b, k, o, s) = (2usize, 6usize, 6usize, 2usize);
    let observed = values(b * k * o, 5, 1.0);
    let mask = binary_mask(b * k * o, 6, 0.7);
    let opts = ForecastOptions {
        num_samples: s,
        sampler: SamplerConfig::ddim(3, 1.0),
    };
    let seeded = CascadeNoise::Seeded {
        seed: 12,
        sequences: Sequences::From(0),
    };
    let one = in_pool(1, || {
        cascade(&short, &long, &observed, &mask, &opts, seeded, &Control::default()).unwrap()
    });
    let two = in_pool(2, || {
        cascade(&short, &long, &observed, &mask, &opts, seeded, &Control::default()).unwrap()
    });
    assert_eq!(one, two);
    let ns = seeded_noise(12, Sequences::From(0), stage::SHORT, s, 4, b, k * 8);
    let nl = seeded_noise(12, Sequences::From(0), stage::LONG, s, 4, b, k * 12);
    let inj = cascade(
        &short,
        &long,
        &observed,
        &mask,
        &opts,
        CascadeNoise::Injected {
            short: &ns,
            long: &nl,
        },
        &Control::default(),
    )
    .unwrap();
    assert_eq!(one, inj);
    let other = cascade(
        &short,
        &long,
        &observed,
        &mask,
        &opts,
        CascadeNoise::Seeded {
            seed: 13,
            sequences: Sequences::From(0),
        },
        &Control::default(),
    )
    .unwrap();
    assert_ne!(one.mean, other.mean);
}

#[test]
fn repair_imputes_only_missing_entries() {
    let (short, _) = models();
    let (b, k, o, s) = (2usize, 6usize, 6usize, 3usize);
    let observed = values(b * k * o, 7, 1.0);
    let mask = binary_mask(b * k * o, 8, 0.6);
    let opts = ForecastOptions {
        num_samples: s,
        sampler: SamplerConfig::ddim(5, 0.0),
    };
    let r = repair(&short, &observed, &mask, b, &opts, Noise::seeded(1), &Control::default()).unwrap();
    assert_eq!(r.mean.len(), b * k * o);
    assert_eq!(r.samples.len(), s * b * k * o);
    for i in 0..b * k * o {
        if mask[i] == 1.0 {
            assert_eq!(r.mean[i].to_bits(), observed[i].to_bits());
            for si in 0..s {
                assert_eq!(
                    r.samples[si * b * k * o + i].to_bits(),
                    observed[i].to_bits()
                );
            }
        } else {
            assert!(r.mean[i].is_finite());
        }
    }
    let again = in_pool(1, || {
        repair(&short, &observed, &mask, b, &opts, Noise::seeded(1), &Control::default()).unwrap()
    });
    assert_eq!(r, again);
}

#[test]
fn cascade_errors() {
    let (short, long) = models();
    let k = 6;
    let observed = values(k * 6, 1, 1.0);
    let mask = vec![1.0f32; k * 6];
    let opts = ForecastOptions {
        num_samples: 1,
        sampler: SamplerConfig::ddim(2, 0.0),
    };
    let seeded = CascadeNoise::Seeded {
        seed: 0,
        sequences: Sequences::From(0),
    };
    // swapped models: the long model's obs_len (8) is not the short seq_len
    let e = cascade(
        &long,
        &short,
        &vec![0.0; k * 8],
        &vec![1.0; k * 8],
        &opts,
        seeded,
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("`long`"), "{e}");
    // wrong observation length
    let e = cascade(&short, &long, &observed[1..], &mask, &opts, seeded, &Control::default()).unwrap_err();
    assert!(e.to_string().contains("`observed`"), "{e}");
    // injected long noise of the wrong size is caught before anything runs
    let ns = vec![0.0f32; 3 * k * 8];
    let nl = vec![0.0f32; 3 * k * 12 - 1];
    let e = cascade(
        &short,
        &long,
        &observed,
        &mask,
        &opts,
        CascadeNoise::Injected {
            short: &ns,
            long: &nl,
        },
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("`noise.long`"), "{e}");
    let zero = ForecastOptions {
        num_samples: 0,
        ..opts
    };
    assert!(cascade(&short, &long, &observed, &mask, &zero, seeded, &Control::default())
        .unwrap_err()
        .to_string()
        .contains("num_samples"));
    // a model with different K
    let mut cfg = tiny_config(Role::Long, 8, 4);
    cfg.model.num_joints = 1;
    cfg.model.num_features = 3;
    let t = random_tensors(&cfg, 1);
    let other = Denoiser::from_bytes(&serialize(&t, Some(cfg.to_json())), "k3").unwrap();
    let e = cascade(&short, &other, &observed, &mask, &opts, seeded, &Control::default()).unwrap_err();
    assert!(e.to_string().contains("num_features"), "{e}");
}
