//! Cascade and repair on tiny models: short (O = 6, L_s = 8) → long (8 + 4 = 12).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use tcd_core::FileConfig;
use tcd_core::{
    cascade, repair, sample, CascadeNoise, Control, Denoiser, Error, ForecastOptions, Noise,
    Observation, Role, SamplerConfig, Sequences,
};
use tcd_core::{seeded_noise, stage, Network};

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
    let noise = CascadeNoise::seeded(4, Sequences::From(0));
    let out = cascade(
        &short,
        &long,
        None,
        &Observation::new(&observed_nan, &mask, [b, k, o]).unwrap(),
        &opts,
        noise,
        &Control::default(),
    )
    .unwrap();
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
        None,
        &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
        &opts,
        CascadeNoise::seeded(8, Sequences::From(0)),
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
        &Observation::new(&x, &m, [1, k, 8]).unwrap(),
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
    let seeded = CascadeNoise::seeded(12, Sequences::From(0));
    let one = in_pool(1, || {
        cascade(
            &short,
            &long,
            None,
            &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
            &opts,
            seeded,
            &Control::default(),
        )
        .unwrap()
    });
    let two = in_pool(2, || {
        cascade(
            &short,
            &long,
            None,
            &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
            &opts,
            seeded,
            &Control::default(),
        )
        .unwrap()
    });
    assert_eq!(one, two);
    let ns = seeded_noise(12, Sequences::From(0), stage::SHORT, s, 4, b, k * 8);
    let nl = seeded_noise(12, Sequences::From(0), stage::LONG, s, 4, b, k * 12);
    let inj = cascade(
        &short,
        &long,
        None,
        &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
        &opts,
        CascadeNoise::injected(&ns, &nl),
        &Control::default(),
    )
    .unwrap();
    assert_eq!(one, inj);
    let other = cascade(
        &short,
        &long,
        None,
        &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
        &opts,
        CascadeNoise::seeded(13, Sequences::From(0)),
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
    let r = repair(
        &short,
        None,
        None,
        &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
        &opts,
        Noise::seeded(1),
        &Control::default(),
    )
    .unwrap();
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
        repair(
            &short,
            None,
            None,
            &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
            &opts,
            Noise::seeded(1),
            &Control::default(),
        )
        .unwrap()
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
    let seeded = CascadeNoise::seeded(0, Sequences::From(0));
    // swapped models: the long model's obs_len (8) is not the short seq_len
    let e = cascade(
        &long,
        &short,
        None,
        &Observation::new(&vec![0.0; k * 8], &vec![1.0; k * 8], [1, k, 8]).unwrap(),
        &opts,
        seeded,
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("`long`"), "{e}");
    // an observation of 5 frames, not the short model's obs_len = 6
    let five = Observation::new(&observed[..k * 5], &mask[..k * 5], [1, k, 5]).unwrap();
    let e = cascade(
        &short,
        &long,
        None,
        &five,
        &opts,
        seeded,
        &Control::default(),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("`observed`") && e.to_string().contains("obs_len"),
        "{e}"
    );
    // a buffer that does not hold the shape it claims is refused when the observation is made
    let e = Observation::new(&observed[1..], &mask, [1, k, 6]).unwrap_err();
    assert!(e.to_string().contains("`observed`"), "{e}");
    // injected long noise of the wrong size is caught before anything runs
    let ns = vec![0.0f32; 3 * k * 8];
    let nl = vec![0.0f32; 3 * k * 12 - 1];
    let e = cascade(
        &short,
        &long,
        None,
        &Observation::new(&observed, &mask, [1, k, 6]).unwrap(),
        &opts,
        CascadeNoise::injected(&ns, &nl),
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("`noise.long`"), "{e}");
    let zero = ForecastOptions {
        num_samples: 0,
        ..opts
    };
    assert!(cascade(
        &short,
        &long,
        None,
        &Observation::new(&observed, &mask, [1, k, 6]).unwrap(),
        &zero,
        seeded,
        &Control::default()
    )
    .unwrap_err()
    .to_string()
    .contains("num_samples"));
    // a model with different K
    let mut cfg = tiny_config(Role::Long, 8, 4);
    cfg.model.num_joints = 1;
    cfg.model.num_features = 3;
    let t = random_tensors(&cfg, 1);
    let other = Denoiser::from_bytes(&serialize(&t, Some(cfg.to_json())), "k3").unwrap();
    let e = cascade(
        &short,
        &other,
        None,
        &Observation::new(&observed, &mask, [1, k, 6]).unwrap(),
        &opts,
        seeded,
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("num_features"), "{e}");
}

// ------------------------------------------------------------------ conditioning on the prior forecaster

/// Short (6 + 2) and long (8 + 4) models with cond_fill prior / target prior_residual (scale 10).
fn prior_models(prediction: tcd_core::PredictionType) -> (Denoiser, Denoiser) {
    let conditioned = |role, o, p, seed| {
        let mut cfg = tiny_config(role, o, p);
        cfg.model.cond_fill = tcd_core::CondFill::Prior;
        cfg.model.target = tcd_core::Target::PriorResidual;
        cfg.model.target_scale = 10.0;
        cfg.diffusion.prediction_type = prediction;
        model_of(&cfg, seed)
    };
    (
        conditioned(Role::Short, 6, 2, 31),
        conditioned(Role::Long, 8, 4, 32),
    )
}

#[test]
fn prior_fill_is_the_spline_then_the_rollout_and_keeps_observed_entries() {
    let prior = tiny_prior(6, 5, 2, 40);
    let (b, k, l, o) = (2usize, 6usize, 12usize, 5usize);
    let mut mask = binary_mask(b * k * l, 41, 0.6);
    // frames 5, 6 of every row given (a long window's teacher-forced frames), 7.. masked
    for row in mask.chunks_exact_mut(l) {
        row[5] = 1.0;
        row[6] = 1.0;
        row[7..].fill(0.0);
    }
    let given = values(b * k * l, 42, 1.0);
    let holes: Vec<f32> = given
        .iter()
        .zip(&mask)
        .map(|(&v, &m)| if m == 1.0 { v } else { f32::NAN })
        .collect();
    let observed = Observation::new(&holes, &mask, [b, k, l]).unwrap();
    let x = tcd_core::prior_fill(&prior, None, &observed, &Control::default()).unwrap();
    // head: the spline over the first O frames of each row
    let mut head = vec![0.0f32; b * o * k];
    for r in 0..b * k {
        let (m, v) = (&mask[r * l..r * l + o], &given[r * l..r * l + o]);
        let mut filled: Vec<f32> = v
            .iter()
            .zip(m)
            .map(|(&v, &m)| if m == 1.0 { v } else { 0.0 })
            .collect();
        tcd_core::fill_spline(m, v, |ll, val| filled[ll] = val);
        for t in 0..o {
            head[((r / k) * o + t) * k + r % k] = filled[t];
        }
    }
    let future = prior
        .predict(&head, b, o, l - o, &Control::default())
        .unwrap();
    for r in 0..b * k {
        let (bb, kk) = (r / k, r % k);
        for ll in 0..l {
            let i = r * l + ll;
            let want = if mask[i] == 1.0 {
                given[i]
            } else if ll < o {
                head[(bb * o + ll) * k + kk]
            } else {
                future[(bb * (l - o) + ll - o) * k + kk]
            };
            assert_eq!(x[i].to_bits(), want.to_bits(), "row {r} frame {ll}");
        }
    }
    // the prior moved the masked future away from the last given value
    assert!((7..l).any(|ll| (x[ll] - x[6]).abs() > 1e-2));
    // errors name the argument
    let n5 = b * k * 5;
    let five = Observation::new(&x[..n5], &mask[..n5], [b, k, 5]).unwrap();
    let e = tcd_core::prior_fill(&prior, None, &five, &Control::default()).unwrap_err();
    assert!(e.to_string().contains("`length`"), "{e}");
    let other_k = Observation::new(&x, &mask, [2 * b, 3, l]).unwrap();
    let e = tcd_core::prior_fill(&prior, None, &other_k, &Control::default()).unwrap_err();
    assert!(
        e.to_string().contains("`observed`") && e.to_string().contains("K = 6"),
        "{e}"
    );
}

#[test]
fn cascade_with_a_prior_conditioned_pair_fills_each_stage_once() {
    use tcd_core::PredictionType;
    let (b, k, o, s) = (2usize, 6usize, 6usize, 2usize);
    let observed = values(b * k * o, 51, 1.0);
    let mut mask = binary_mask(b * k * o, 52, 0.7);
    mask[3] = 0.0;
    let mut observed_nan = observed.clone();
    observed_nan[3] = f32::NAN;
    let prior = tiny_prior(6, 5, 2, 53);
    for prediction in [PredictionType::Epsilon, PredictionType::Sample] {
        let (short, long) = prior_models(prediction);
        for sampler in [
            SamplerConfig::ddpm(),
            SamplerConfig::ddim(4, 1.0),
            SamplerConfig::dpmpp2m(4),
        ] {
            let opts = ForecastOptions {
                num_samples: s,
                sampler,
            };
            let plan = sampler
                .plan(short.schedule(), tcd_core::VarianceType::FixedSmall)
                .unwrap();
            let blocks = plan.num_noise_blocks();
            let ns = values(s * blocks * b * k * 8, 54, 1.5);
            let nl = values(s * blocks * b * k * 12, 55, 1.5);
            let noise = CascadeNoise::injected(&ns, &nl);
            let out = cascade(
                &short,
                &long,
                Some(&prior),
                &Observation::new(&observed_nan, &mask, [b, k, o]).unwrap(),
                &opts,
                noise,
                &Control::default(),
            )
            .unwrap();
            assert!(out
                .samples
                .iter()
                .chain(&out.short_mean)
                .all(|v| v.is_finite()));
            // The same from the public pieces: each stage's observation filled by prior_fill, then sample.
            let pad = |src: &[f32], len: usize, new: usize, v: f32| -> Vec<f32> {
                src.chunks_exact(len)
                    .flat_map(|r| r.iter().copied().chain(std::iter::repeat_n(v, new - len)))
                    .collect()
            };
            let zeroed: Vec<f32> = observed
                .iter()
                .zip(&mask)
                .map(|(&v, &m)| if m == 1.0 { v } else { 0.0 })
                .collect();
            let ms = pad(&mask, o, 8, 0.0);
            let xs = tcd_core::prior_fill(
                &prior,
                None,
                &Observation::new(&pad(&zeroed, o, 8, 0.0), &ms, [b, k, 8]).unwrap(),
                &Control::default(),
            )
            .unwrap();
            let ss = sample(
                &short,
                &Observation::new(&xs, &ms, [b, k, 8]).unwrap(),
                s,
                &sampler,
                Noise::Injected(&ns),
                &Control::default(),
            )
            .unwrap();
            let n = b * k * 8;
            let mut mean = vec![0.0f32; n];
            for chunk in ss.chunks_exact(n) {
                mean.iter_mut().zip(chunk).for_each(|(a, v)| *a += v);
            }
            mean.iter_mut().for_each(|a| *a /= s as f32);
            for i in 0..n {
                if ms[i] == 1.0 {
                    mean[i] = xs[i];
                }
            }
            assert_eq!(out.short_mean, mean, "{prediction:?} {sampler:?}");
            let ml = pad(&vec![1.0; b * k * 8], 8, 12, 0.0);
            let xl = tcd_core::prior_fill(
                &prior,
                None,
                &Observation::new(&pad(&mean, 8, 12, 0.0), &ml, [b, k, 12]).unwrap(),
                &Control::default(),
            )
            .unwrap();
            let ls = sample(
                &long,
                &Observation::new(&xl, &ml, [b, k, 12]).unwrap(),
                s,
                &sampler,
                Noise::Injected(&nl),
                &Control::default(),
            )
            .unwrap();
            let future: Vec<f32> = ls
                .chunks_exact(12)
                .flat_map(|r| r[o..].iter().copied())
                .collect();
            assert_eq!(out.samples, future, "{prediction:?} {sampler:?}");
        }
        // Another prior gives another forecast: the fill reaches the network.
        let opts = ForecastOptions {
            num_samples: 1,
            sampler: SamplerConfig::ddim(3, 0.0),
        };
        let seeded = CascadeNoise::seeded(5, Sequences::From(0));
        let one = cascade(
            &short,
            &long,
            Some(&prior),
            &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
            &opts,
            seeded,
            &Control::default(),
        )
        .unwrap();
        let other_prior = tiny_prior(6, 5, 2, 99);
        let two = cascade(
            &short,
            &long,
            Some(&other_prior),
            &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
            &opts,
            seeded,
            &Control::default(),
        )
        .unwrap();
        assert_ne!(one.mean, two.mean);
        // seeded results do not depend on the thread count
        let again = in_pool(1, || {
            cascade(
                &short,
                &long,
                Some(&prior),
                &Observation::new(&observed, &mask, [b, k, o]).unwrap(),
                &opts,
                seeded,
                &Control::default(),
            )
            .unwrap()
        });
        assert_eq!(one, again);
    }
}

#[test]
fn prior_conditioned_models_need_a_fitting_prior_and_repair_only_with_a_fill() {
    let (short, long) = prior_models(tcd_core::PredictionType::Epsilon);
    let (plain_short, plain_long) = models();
    let (k, o) = (6usize, 6usize);
    let observed = values(k * o, 61, 1.0);
    let mask = vec![1.0f32; k * o];
    let opts = ForecastOptions {
        num_samples: 1,
        sampler: SamplerConfig::ddim(2, 0.0),
    };
    let seeded = CascadeNoise::seeded(0, Sequences::From(0));
    let run = |s: &Denoiser, l: &Denoiser, p: Option<&tcd_core::Prior>| {
        cascade(
            s,
            l,
            p,
            &Observation::new(&observed, &mask, [1, k, o]).unwrap(),
            &opts,
            seeded,
            &Control::default(),
        )
    };
    // no prior: refused, naming `prior` and the stage that needs it
    for (s, l, which) in [
        (&short, &long, "short-term"),
        (&plain_short, &long, "long-term"),
    ] {
        let e = run(s, l, None).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidInput { argument, .. } if argument == "prior"),
            "{e:?}"
        );
        assert!(
            e.to_string().contains(which) && e.to_string().contains("cond_fill \"prior\""),
            "{e}"
        );
    }
    // a prior of another K, or one that reads the whole window
    for p in [tiny_prior(3, 5, 2, 1), tiny_prior(6, 8, 2, 1)] {
        let e = run(&short, &long, Some(&p)).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidInput { argument, .. } if argument == "prior"),
            "{e:?}"
        );
        assert!(e.to_string().contains("num_features = 6"), "{e}");
    }
    // a prior reading 8 frames fits the long model (12) but not the short one (8)
    let e = run(&plain_short, &long, Some(&tiny_prior(6, 8, 2, 1))).unwrap();
    assert!(e.mean.iter().all(|v| v.is_finite()));
    // unused by models not conditioned on it
    let p = tiny_prior(6, 5, 2, 1);
    assert_eq!(
        run(&plain_short, &plain_long, Some(&p)).unwrap(),
        run(&plain_short, &plain_long, None).unwrap()
    );
    // repair runs a prior-conditioned model only with a repair fill (anchor "window") of its window: none,
    // or a forecaster, is refused naming `fill`
    for f in [None, Some(&p)] {
        let e = repair(
            &short,
            f,
            None,
            &Observation::new(&observed, &mask, [1, k, o]).unwrap(),
            &ForecastOptions::default(),
            Noise::seeded(1),
            &Control::default(),
        )
        .unwrap_err();
        assert!(
            matches!(&e, Error::InvalidInput { argument, .. } if argument == "fill"),
            "{e:?}"
        );
        assert!(e.to_string().contains("repair fill"), "{e}");
    }
    // and a forecasting cascade refuses a repair fill as its prior
    let e = run(&short, &long, Some(&tiny_repair_fill(6, 5, 1))).unwrap_err();
    assert!(e.to_string().contains("anchor \"window\""), "{e}");
    // the low-level calls read the fill from `observed`: it must be finite there
    let mut nan = values(k * 8, 62, 1.0);
    let m8: Vec<f32> = (0..k * 8)
        .map(|i| if i % 8 < 6 { 1.0 } else { 0.0 })
        .collect();
    nan[7] = f32::NAN;
    let e = sample(
        &short,
        &Observation::new(&nan, &m8, [1, k, 8]).unwrap(),
        1,
        &SamplerConfig::ddim(2, 0.0),
        Noise::seeded(0),
        &Control::default(),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("`observed`") && e.to_string().contains("finite everywhere"),
        "{e}"
    );
    let mut out = vec![0.0f32; k * 8];
    let e = short
        .forward(
            &values(k * 8, 63, 1.0),
            &Observation::new(&nan, &m8, [1, k, 8]).unwrap(),
            0,
            &mut out,
        )
        .unwrap_err();
    assert!(e.to_string().contains("`observed`"), "{e}");
}

/// A repair model (K 6, 8 + 0 frames) conditioned on a fill (cond_fill "prior", the residual over it ×10)
/// and a repair fill of its window.
fn repair_model_and_fill() -> (Denoiser, tcd_core::Prior) {
    let mut cfg = tiny_config(Role::Repair, 8, 0);
    cfg.model.cond_fill = tcd_core::CondFill::Prior;
    cfg.model.target = tcd_core::Target::PriorResidual;
    cfg.model.target_scale = 10.0;
    (model_of(&cfg, 71), tiny_repair_fill(6, 8, 72))
}

#[test]
fn repair_with_a_fill_samples_the_model_on_the_filled_window() {
    // A repair model conditioned on a fill (cond_fill "prior", pred_len 0) and a repair fill of its window:
    // the repair is the model's sampling of the observation whose masked entries hold prior_fill's
    // correction of the spline (the same noise), observed entries exact.
    let (model, fill) = repair_model_and_fill();
    let (b, k, l, s) = (2usize, 6usize, 8usize, 3usize);
    let given = values(b * k * l, 73, 1.0);
    let mask = binary_mask(b * k * l, 74, 0.6);
    let observed = Observation::new(&given, &mask, [b, k, l]).unwrap();
    let opts = ForecastOptions {
        num_samples: s,
        sampler: SamplerConfig::ddim(3, 1.0),
    };
    let r = repair(
        &model,
        Some(&fill),
        None,
        &observed,
        &opts,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap();
    let filled = tcd_core::prior_fill(&fill, None, &observed, &Control::default()).unwrap();
    // the fill corrects the spline: it differs from it on masked entries, equals the observation elsewhere
    let spline = tcd_core::fill_rows(tcd_core::CondFill::Spline, l, &mask, &given).unwrap();
    assert!((0..b * k * l).any(|i| mask[i] == 0.0 && filled[i] != spline[i]));
    let want = sample(
        &model,
        &Observation::new(&filled, &mask, [b, k, l]).unwrap(),
        s,
        &opts.sampler,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap();
    assert_eq!(r.samples, want);
    for i in 0..b * k * l {
        if mask[i] == 1.0 {
            assert_eq!(r.mean[i].to_bits(), given[i].to_bits());
        }
    }
}

#[test]
fn repair_of_no_samples_is_the_fill_alone() {
    // num_samples 0: the window the chains would start from (prior_fill's), over the observed frames, for any
    // sampler and seed; no samples. Injected noise must then be empty, and a model without a fill refuses 0.
    let (model, fill) = repair_model_and_fill();
    let (b, k, l) = (2usize, 6usize, 8usize);
    let given = values(b * k * l, 75, 1.0);
    let mask = binary_mask(b * k * l, 76, 0.6);
    let observed = Observation::new(&given, &mask, [b, k, l]).unwrap();
    let want = tcd_core::prior_fill(&fill, None, &observed, &Control::default()).unwrap();
    for (sampler, noise) in [
        (SamplerConfig::ddim(3, 1.0), Noise::seeded(5)),
        (SamplerConfig::ddpm(), Noise::seeded(6)),
        (SamplerConfig::ddim(3, 1.0), Noise::Injected(&[])),
    ] {
        let opts = ForecastOptions {
            num_samples: 0,
            sampler,
        };
        let r = repair(
            &model,
            Some(&fill),
            None,
            &observed,
            &opts,
            noise,
            &Control::default(),
        )
        .unwrap();
        assert_eq!(
            (r.num_samples, r.samples.len(), r.batch, r.obs_len),
            (0, 0, b, l)
        );
        assert_eq!(r.mean, want);
        assert!((0..b * k * l).any(|i| mask[i] == 0.0 && r.mean[i] != given[i]));
    }
    let opts = ForecastOptions {
        num_samples: 0,
        sampler: SamplerConfig::ddim(3, 1.0),
    };
    let e = repair(
        &model,
        Some(&fill),
        None,
        &observed,
        &opts,
        Noise::Injected(&[0.0]),
        &Control::default(),
    )
    .unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput { argument, .. } if argument == "noise"),
        "{e}"
    );
    let plain = model_of(&tiny_config(Role::Repair, 8, 0), 77);
    let e = repair(
        &plain,
        None,
        None,
        &observed,
        &opts,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput { argument, .. } if argument == "num_samples"),
        "{e}"
    );
    assert!(e.to_string().contains("repair fill"), "{e}");
}

/// The gap fill's steps written out once more, one gap and one side at a time (as
/// `training.model.fill_gaps` states them): the history padded at its start, the forecast of n + 1 frames, its linear
/// correction towards the far frame, the blend, the average with the fill there.
fn gap_fill_reference(
    forecaster: &tcd_core::Prior,
    base: &[f32],
    (b, s, e): (usize, usize, usize),
    (k, l): (usize, usize),
) -> Vec<Vec<f32>> {
    let o = forecaster.obs_len();
    let frame = |t: usize| -> Vec<f32> { (0..k).map(|kk| base[(b * k + kk) * l + t]).collect() };
    let forecast = |frames: Vec<usize>, n: usize| -> Vec<Vec<f32>> {
        // the prior's history: the last o frames, or the first repeated before them
        let mut h: Vec<usize> = frames.iter().rev().take(o).rev().copied().collect();
        while h.len() < o {
            h.insert(0, h[0]);
        }
        let obs: Vec<f32> = h.iter().flat_map(|&t| frame(t)).collect();
        let out = forecaster
            .predict(&obs, 1, o, n + 1, &Control::default())
            .unwrap();
        out.chunks_exact(k).map(|c| c.to_vec()).collect()
    };
    let n = e - s;
    let w = |i: usize| (i + 1) as f32 / (n + 1) as f32;
    let fwd = (s > 0).then(|| {
        let f = forecast((0..s).collect(), n);
        (0..n)
            .map(|i| {
                (0..k)
                    .map(|kk| match e < l {
                        true => f[i][kk] + w(i) * (frame(e)[kk] - f[n][kk]),
                        false => f[i][kk],
                    })
                    .collect::<Vec<f32>>()
            })
            .collect::<Vec<_>>()
    });
    let bwd = (e < l).then(|| {
        let r = forecast((e..l).rev().collect(), n);
        let mut v: Vec<Vec<f32>> = (0..n)
            .map(|j| {
                (0..k)
                    .map(|kk| match s > 0 {
                        true => r[j][kk] + w(j) * (frame(s - 1)[kk] - r[n][kk]),
                        false => r[j][kk],
                    })
                    .collect()
            })
            .collect();
        v.reverse();
        v
    });
    (0..n)
        .map(|i| {
            (0..k)
                .map(|kk| {
                    let both = match (&fwd, &bwd) {
                        (Some(f), Some(g)) => (1.0 - w(i)) * f[i][kk] + w(i) * g[i][kk],
                        (Some(f), None) => f[i][kk],
                        (None, Some(g)) => g[i][kk],
                        (None, None) => unreachable!(),
                    };
                    0.5 * (both + frame(s + i)[kk])
                })
                .collect()
        })
        .collect()
}

#[test]
fn a_gap_filling_repair_fill_fills_whole_frame_gaps_from_both_sides() {
    // Four windows of 10 frames: a gap inside; one at the start (plus scattered hidden entries); one
    // at the end and one single frame inside; everything hidden (no gap filled: nothing to fill from).
    let (b, k, l) = (4usize, 6usize, 10usize);
    let forecaster = tiny_prior(k, 6, 2, 81);
    let plain = tiny_repair_fill(k, l, 82);
    let gapped = tiny_gap_repair_fill(k, l, 82); // the same weights
    let given = values(b * k * l, 83, 1.0);
    let mut mask = binary_mask(b * k * l, 84, 0.8);
    let gaps = [(0usize, 3usize, 6usize), (1, 0, 2), (2, 7, 10), (2, 2, 3)];
    for &(bb, s, e) in &gaps {
        for kk in 0..k {
            for t in s..e {
                mask[(bb * k + kk) * l + t] = 0.0;
            }
        }
    }
    // every other frame keeps an observed entry, so that the gaps are exactly these
    for bb in 0..3 {
        for t in 0..l {
            if !gaps.iter().any(|&(g, s, e)| g == bb && (s..e).contains(&t)) {
                mask[(bb * k) * l + t] = 1.0;
            }
        }
    }
    for v in &mut mask[3 * k * l..] {
        *v = 0.0;
    }
    let observed = Observation::new(&given, &mask, [b, k, l]).unwrap();
    let control = Control::default();
    let base = tcd_core::prior_fill(&plain, None, &observed, &control).unwrap();
    let got = tcd_core::prior_fill(&gapped, Some(&forecaster), &observed, &control).unwrap();
    let mut in_gap = vec![false; b * k * l];
    for &(bb, s, e) in &gaps {
        let want = gap_fill_reference(&forecaster, &base, (bb, s, e), (k, l));
        for (t, want_t) in (s..e).zip(&want) {
            for (kk, &w) in want_t.iter().enumerate() {
                let at = (bb * k + kk) * l + t;
                in_gap[at] = true;
                assert!(
                    (got[at] - w).abs() <= 1e-5 * (1.0 + w.abs()),
                    "sequence {bb}, frame {t}, feature {kk}: {} against {w}",
                    got[at]
                );
                assert_ne!(got[at], base[at]);
            }
        }
    }
    // outside the gaps (the all-hidden window included) the repair fill's own values, bit for bit
    for i in (0..b * k * l).filter(|&i| !in_gap[i]) {
        assert_eq!(got[i].to_bits(), base[i].to_bits(), "entry {i}");
    }

    // The forecaster is required, a forecaster (anchor "last") with the fill's K; repair needs it too.
    let named = |e: Error| assert!(e.to_string().contains("`forecaster`"), "{e}");
    named(tcd_core::prior_fill(&gapped, None, &observed, &control).unwrap_err());
    named(tcd_core::prior_fill(&gapped, Some(&plain), &observed, &control).unwrap_err());
    named(
        tcd_core::prior_fill(&gapped, Some(&tiny_prior(9, 6, 2, 1)), &observed, &control)
            .unwrap_err(),
    );
    let mut cfg = tiny_config(Role::Repair, l, 0);
    cfg.model.cond_fill = tcd_core::CondFill::Prior;
    cfg.model.target = tcd_core::Target::PriorResidual;
    cfg.model.target_scale = 10.0;
    let model = model_of(&cfg, 85);
    let opts = ForecastOptions {
        num_samples: 2,
        sampler: SamplerConfig::ddim(2, 1.0),
    };
    let run = |fill, forecaster| {
        repair(
            &model,
            Some(fill),
            forecaster,
            &observed,
            &opts,
            Noise::seeded(3),
            &control,
        )
    };
    named(run(&gapped, None).unwrap_err());
    // the repair samples the model on the gap-filled window
    let r = run(&gapped, Some(&forecaster)).unwrap();
    let want = sample(
        &model,
        &Observation::new(&got, &mask, [b, k, l]).unwrap(),
        2,
        &opts.sampler,
        Noise::seeded(3),
        &control,
    )
    .unwrap();
    assert_eq!(r.samples, want);
    // a fill without gap filling ignores a forecaster given to it
    assert_eq!(
        run(&plain, Some(&forecaster)).unwrap().samples,
        run(&plain, None).unwrap().samples
    );
}
