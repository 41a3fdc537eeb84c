//! Samplers: invariants (observed entries unchanged), thread-count independence, seeding,
//! injected vs seeded noise, DDIM determinism.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::OnceLock;

use common::*;
use proptest::prelude::*;
use tcd_core::{
    sample, Control, Denoiser, Error, Noise, Observation, PredictionType, Role, Sampler,
    SamplerConfig, SamplerKind, Sequences, TimestepSpacing, VarianceType,
};
use tcd_core::{seeded_noise, stage, NoiseCoupling};

fn model() -> &'static Denoiser {
    static M: OnceLock<Denoiser> = OnceLock::new();
    M.get_or_init(|| tiny_model(Role::Short, 5, 2, 21).0)
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

fn sampler_strategy() -> impl Strategy<Value = SamplerConfig> {
    prop_oneof![
        (1usize..=10, 0usize..3).prop_map(|(n, sp)| SamplerConfig {
            kind: SamplerKind::Ddpm,
            num_inference_steps: Some(n),
            timestep_spacing: [
                TimestepSpacing::Leading,
                TimestepSpacing::Trailing,
                TimestepSpacing::Linspace
            ][sp],
            ..SamplerConfig::default()
        }),
        (1usize..=10, 0.0f64..=1.0, any::<bool>()).prop_map(|(n, eta, centred)| SamplerConfig {
            noise_coupling: if centred {
                NoiseCoupling::Centered
            } else {
                NoiseCoupling::Independent
            },
            ..SamplerConfig::ddim(n, eta)
        }),
        (1usize..=10).prop_map(SamplerConfig::dpmpp2m),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// Observed entries come back bit-identical; results do not depend on the thread count.
    #[test]
    fn observed_unchanged_and_thread_independent(
        batch in 1usize..3,
        length in 1usize..8,
        num_samples in 1usize..3,
        seed in any::<u64>(),
        p_obs in 0.0f64..1.0,
        sampler in sampler_strategy(),
    ) {
        let m = model();
        let n = batch * 6 * length;
        let observed = values(n, seed ^ 1, 3.0);
        let mask = binary_mask(n, seed ^ 2, p_obs);
        let run = |threads| in_pool(threads, || {
            sample(m, &Observation::new(&observed, &mask, [batch, 6, length]).unwrap(), num_samples, &sampler, Noise::seeded(seed), &Control::default()).unwrap()
        });
        let one = run(1);
        let two = run(2);
        prop_assert_eq!(one.len(), num_samples * n);
        prop_assert!(one.iter().all(|v| v.is_finite()));
        for (i, v) in one.iter().enumerate() {
            if mask[i % n] == 1.0 {
                prop_assert_eq!(v.to_bits(), observed[i % n].to_bits());
            }
        }
        prop_assert_eq!(
            one.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            two.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}

/// Chains left over after whole rounds (5 chains on 2 or 3 threads, 3 on 2) split their forwards
/// over the idle threads: still the same bits as on one thread.
#[test]
fn leftover_chains_split_over_threads_same_bits() {
    let m = model();
    for (batch, num_samples) in [(1usize, 5usize), (1, 3), (3, 1)] {
        let n = batch * 6 * 9;
        let observed = values(n, 11, 1.0);
        let mask = binary_mask(n, 12, 0.4);
        let run = |threads| {
            in_pool(threads, || {
                sample(
                    m,
                    &Observation::new(&observed, &mask, [batch, 6, 9]).unwrap(),
                    num_samples,
                    &SamplerConfig::ddpm(),
                    Noise::seeded(3),
                    &Control::default(),
                )
                .unwrap()
            })
        };
        let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
        let one = bits(run(1));
        for threads in [2, 3, 4] {
            assert_eq!(
                one,
                bits(run(threads)),
                "batch {batch}, samples {num_samples}, threads {threads}"
            );
        }
    }
}

#[test]
fn same_seed_same_output_different_seed_differs() {
    let m = model();
    let n = 2 * 6 * 7;
    let observed = values(n, 1, 1.0);
    let mask = binary_mask(n, 2, 0.5);
    let cfg = SamplerConfig::ddpm();
    let a = sample(
        m,
        &Observation::new(&observed, &mask, [2, 6, 7]).unwrap(),
        2,
        &cfg,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap();
    let b = sample(
        m,
        &Observation::new(&observed, &mask, [2, 6, 7]).unwrap(),
        2,
        &cfg,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap();
    let c = sample(
        m,
        &Observation::new(&observed, &mask, [2, 6, 7]).unwrap(),
        2,
        &cfg,
        Noise::seeded(6),
        &Control::default(),
    )
    .unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    // the two samples of a sequence differ
    assert_ne!(&a[..n], &a[n..]);
}

#[test]
fn seeded_equals_injected_seeded_noise_and_batch_composition_is_irrelevant() {
    let m = model();
    let (b, l, s) = (3usize, 7usize, 2usize);
    let n = b * 6 * l;
    let observed = values(n, 3, 1.0);
    let mask = binary_mask(n, 4, 0.4);
    let cfg = SamplerConfig::ddim(4, 0.7);
    let seeded = sample(
        m,
        &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::seeded(9),
        &Control::default(),
    )
    .unwrap();
    let noise = seeded_noise(9, Sequences::From(0), stage::SHORT, s, 5, b, 6 * l);
    let injected = sample(
        m,
        &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&noise),
        &Control::default(),
    )
    .unwrap();
    assert_eq!(seeded, injected);
    // sequence 2 alone, numbered 2, gives the same samples as inside the batch
    let q = 6 * l;
    let alone = sample(
        m,
        &Observation::new(&observed[2 * q..], &mask[2 * q..], [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Seeded {
            seed: 9,
            sequences: Sequences::From(2),
        },
        &Control::default(),
    )
    .unwrap();
    for si in 0..s {
        assert_eq!(
            &alone[si * q..(si + 1) * q],
            &seeded[(si * b + 2) * q..(si * b + 3) * q]
        );
    }
}

/// Centred noise: the seeded call equals the injected one fed the same raw streams (the coupling is applied to
/// either source); one DDIM step from x_T is x_T's function, so moving x_T off the sequence's mean changes the
/// samples; a sequence's centre is its own (the same alone and in a batch); one chain per sequence is not coupled.
#[test]
fn centred_noise_is_the_same_for_seeded_and_injected_calls() {
    let m = model();
    let (b, l, s) = (3usize, 7usize, 4usize);
    let n = b * 6 * l;
    let observed = values(n, 5, 1.0);
    let mask = binary_mask(n, 6, 0.5);
    let obs = Observation::new(&observed, &mask, [b, 6, l]).unwrap();
    let centred = SamplerConfig {
        noise_coupling: NoiseCoupling::Centered,
        ..SamplerConfig::ddim(1, 0.0)
    };
    let run = |cfg: &SamplerConfig, noise: Noise, obs: &Observation, s: usize| {
        sample(m, obs, s, cfg, noise, &Control::default()).unwrap()
    };
    let seeded = run(&centred, Noise::seeded(3), &obs, s);
    let raw = seeded_noise(3, Sequences::From(0), stage::SHORT, s, 2, b, 6 * l);
    assert_eq!(seeded, run(&centred, Noise::Injected(&raw), &obs, s));
    assert_ne!(
        seeded,
        run(&SamplerConfig::ddim(1, 0.0), Noise::seeded(3), &obs, s)
    );
    let q = 6 * l;
    let alone = run(
        &centred,
        Noise::Seeded {
            seed: 3,
            sequences: Sequences::From(1),
        },
        &Observation::new(&observed[q..2 * q], &mask[q..2 * q], [1, 6, l]).unwrap(),
        s,
    );
    for si in 0..s {
        assert_eq!(
            &alone[si * q..(si + 1) * q],
            &seeded[(si * b + 1) * q..(si * b + 2) * q]
        );
    }
    assert_eq!(
        run(&centred, Noise::seeded(3), &obs, 1),
        run(&SamplerConfig::ddim(1, 0.0), Noise::seeded(3), &obs, 1)
    );
}

#[test]
fn ddim_eta_zero_ignores_the_step_noise() {
    let m = model();
    let (l, s) = (7usize, 1usize);
    let n = 6 * l;
    let observed = values(n, 3, 1.0);
    let mask = binary_mask(n, 4, 0.4);
    let cfg = SamplerConfig::ddim(5, 0.0);
    let mut noise = seeded_noise(1, Sequences::From(0), 0, s, 6, 1, n);
    let a = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&noise),
        &Control::default(),
    )
    .unwrap();
    for v in noise[n..].iter_mut() {
        *v = -*v * 3.0; // change every z, keep x_T
    }
    let b = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&noise),
        &Control::default(),
    )
    .unwrap();
    assert_eq!(a, b);
    // DDPM does use it
    let cfg = SamplerConfig {
        kind: SamplerKind::Ddpm,
        num_inference_steps: Some(5),
        timestep_spacing: TimestepSpacing::Trailing,
        ..SamplerConfig::default()
    };
    let c = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&noise),
        &Control::default(),
    )
    .unwrap();
    noise[n + 3] += 1.0;
    let d = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&noise),
        &Control::default(),
    )
    .unwrap();
    assert_ne!(c, d);
}

#[test]
fn ddpm_all_steps_is_the_reference_chain() {
    // Explicit n = T with any spacing equals the default reference sampler.
    let m = model();
    let n = 6 * 7;
    let observed = values(n, 3, 1.0);
    let mask = binary_mask(n, 4, 0.4);
    let reference = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
        1,
        &SamplerConfig::ddpm(),
        Noise::seeded(3),
        &Control::default(),
    )
    .unwrap();
    for sp in [TimestepSpacing::Leading, TimestepSpacing::Linspace] {
        let cfg = SamplerConfig {
            kind: SamplerKind::Ddpm,
            num_inference_steps: Some(10),
            timestep_spacing: sp,
            ..SamplerConfig::default()
        };
        assert_eq!(
            sample(
                m,
                &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
                1,
                &cfg,
                Noise::seeded(3),
                &Control::default()
            )
            .unwrap(),
            reference
        );
    }
    // and a hand-written DDPM loop over the public forward (the operations of
    // training/diffusion.py::sample) gives the same bits
    let noise = seeded_noise(3, Sequences::From(0), 0, 1, 11, 1, n);
    let ab = m.schedule().alphas_cumprod().to_vec();
    let abar = |t: i64| if t < 0 { 1.0 } else { ab[t as usize] };
    let mut x = noise[..n].to_vec();
    let mut eps = vec![0.0f32; n];
    for (i, t) in (0..10usize).rev().enumerate() {
        m.forward(
            &x,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            t,
            &mut eps,
        )
        .unwrap();
        let (a_t, a_next) = (abar(t as i64), abar(t as i64 - 1));
        let beta = 1.0 - a_t / a_next;
        let c1 = (1.0 / (1.0 - beta).sqrt()) as f32;
        let c2 = (beta / (1.0 - a_t).sqrt()) as f32;
        for (xv, ev) in x.iter_mut().zip(&eps) {
            *xv = c1 * (*xv - c2 * ev);
        }
        if t > 0 {
            let sigma = (beta * (1.0 - a_next) / (1.0 - a_t)).sqrt() as f32;
            for (xv, zv) in x.iter_mut().zip(&noise[(i + 1) * n..(i + 2) * n]) {
                *xv += sigma * zv;
            }
        }
    }
    for i in 0..n {
        if mask[i] == 1.0 {
            x[i] = observed[i];
        }
    }
    assert_eq!(x, reference);
}

#[test]
fn dpmpp2m_is_deterministic_with_one_noise_block_and_matches_a_hand_loop() {
    let m = model();
    let (l, s) = (7usize, 2usize);
    let n = 6 * l;
    let observed = values(n, 3, 1.0);
    let mask = binary_mask(n, 4, 0.4);
    let cfg = SamplerConfig::dpmpp2m(4);
    let plan = cfg.plan(m.schedule(), VarianceType::FixedSmall).unwrap();
    assert_eq!(plan.num_noise_blocks(), 1);
    assert!(plan.is_multistep());
    let seeded = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::seeded(5),
        &Control::default(),
    )
    .unwrap();
    let noise = seeded_noise(5, Sequences::From(0), stage::SHORT, s, 1, 1, n);
    assert_eq!(
        sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
            s,
            &cfg,
            Noise::Injected(&noise),
            &Control::default()
        )
        .unwrap(),
        seeded
    );
    // n + 1 blocks are refused
    let long = seeded_noise(5, Sequences::From(0), stage::SHORT, s, 5, 1, n);
    let e = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
        s,
        &cfg,
        Noise::Injected(&long),
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("(2, 1, 1, 6, 7)"), "{e}");
    // a hand-written DPM-Solver++(2M) loop over the public forward (training/diffusion.py's formulas)
    let ab = m.schedule().alphas_cumprod().to_vec();
    let ts = plan.timesteps();
    let lam = |t: usize| 0.5 * ab[t].ln() - 0.5 * (1.0 - ab[t]).ln();
    let mut x = noise[n..2 * n].to_vec(); // sample 1
    let mut eps = vec![0.0f32; n];
    let mut prev: Vec<f32> = Vec::new();
    let mut h_prev = 0.0f64;
    for (i, &t) in ts.iter().enumerate() {
        m.forward(
            &x,
            &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
            t,
            &mut eps,
        )
        .unwrap();
        let (a, b) = ((1.0 - ab[t]).sqrt() as f32, ab[t].sqrt() as f32);
        let x0: Vec<f32> = x
            .iter()
            .zip(&eps)
            .map(|(xv, ev)| (xv - a * ev) / b)
            .collect();
        if i + 1 == ts.len() {
            x = x0;
            break;
        }
        let tn = ts[i + 1];
        let h = lam(tn) - lam(t);
        let cx = ((1.0 - ab[tn]).sqrt() / (1.0 - ab[t]).sqrt()) as f32;
        let c0 = (-ab[tn].sqrt() * (-h).exp_m1()) as f32;
        for j in 0..n {
            let d = if i == 0 {
                x0[j]
            } else {
                let r = h_prev / h;
                (1.0 + 0.5 / r) as f32 * x0[j] + (-0.5 / r) as f32 * prev[j]
            };
            x[j] = cx * x[j] + c0 * d;
        }
        prev = x0;
        h_prev = h;
    }
    for i in 0..n {
        if mask[i] == 1.0 {
            x[i] = observed[i];
        }
    }
    assert_eq!(&x[..], &seeded[n..]);
}

#[test]
fn sampling_errors() {
    let m = model();
    let n = 6 * 7;
    let observed = values(n, 3, 1.0);
    let mask = binary_mask(n, 4, 0.4);
    let arg = |e: tcd_core::Error| match e {
        tcd_core::Error::InvalidInput { argument, .. } => argument,
        other => panic!("{other:?}"),
    };
    let ddim = |k, eta| SamplerConfig::ddim(k, eta);
    assert_eq!(
        arg(sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            1,
            &ddim(11, 0.0),
            Noise::seeded(0),
            &Control::default()
        )
        .unwrap_err()),
        "num_inference_steps"
    );
    assert_eq!(
        arg(sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            1,
            &ddim(0, 0.0),
            Noise::seeded(0),
            &Control::default()
        )
        .unwrap_err()),
        "num_inference_steps"
    );
    assert_eq!(
        arg(sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            1,
            &ddim(3, 1.5),
            Noise::seeded(0),
            &Control::default()
        )
        .unwrap_err()),
        "eta"
    );
    assert_eq!(
        arg(sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            0,
            &ddim(3, 0.0),
            Noise::seeded(0),
            &Control::default()
        )
        .unwrap_err()),
        "num_samples"
    );
    let short = vec![0.0f32; 4 * n - 1];
    let e = sample(
        m,
        &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
        1,
        &ddim(3, 0.0),
        Noise::Injected(&short),
        &Control::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("(1, 4, 1, 6, 7)"), "{e}");
    let mut nan = vec![0.0f32; 4 * n];
    nan[7] = f32::NAN;
    assert_eq!(
        arg(sample(
            m,
            &Observation::new(&observed, &mask, [1, 6, 7]).unwrap(),
            1,
            &ddim(3, 0.0),
            Noise::Injected(&nan),
            &Control::default()
        )
        .unwrap_err()),
        "noise"
    );
}

#[test]
fn control_counts_forwards_and_stops_the_call() {
    let m = model();
    let n = 2 * 6 * 7;
    let observed = values(n, 1, 1.0);
    let mask = binary_mask(n, 2, 0.5);
    let cfg = SamplerConfig::ddpm(); // 10 training steps in the tiny model
    let run = |control: &Control| {
        sample(
            m,
            &Observation::new(&observed, &mask, [2, 6, 7]).unwrap(),
            3,
            &cfg,
            Noise::seeded(5),
            control,
        )
    };
    // counted: 3 samples x 2 sequences x 10 steps, all of them done
    let counted = Control::default();
    let a = run(&counted).unwrap();
    assert_eq!(
        (counted.forwards_done(), counted.forwards_total()),
        (60, 60)
    );
    // cancelled before it starts: no forward runs
    let stopped = Control::default();
    stopped.cancel();
    assert!(matches!(run(&stopped), Err(Error::Cancelled)));
    assert_eq!((stopped.forwards_done(), stopped.forwards_total()), (0, 60));
    // cancelled from another thread while it runs: the call returns Cancelled, having stopped early
    let big = 2 * 6 * 7 * 40;
    let (observed, mask) = (values(big, 3, 1.0), binary_mask(big, 4, 0.5));
    let control = Control::default();
    std::thread::scope(|s| {
        let h = s.spawn(|| {
            sample(
                m,
                &Observation::new(&observed, &mask, [80, 6, 7]).unwrap(),
                50,
                &cfg,
                Noise::seeded(1),
                &control,
            )
        });
        while control.forwards_done() == 0 {
            std::thread::yield_now();
        }
        control.cancel();
        assert!(matches!(h.join().unwrap(), Err(Error::Cancelled)));
    });
    assert!(
        control.forwards_done() < control.forwards_total(),
        "{} of {}",
        control.forwards_done(),
        control.forwards_total()
    );
    // a control that was only read does not change results
    assert_eq!(a, run(&Control::default()).unwrap());
}

#[test]
fn x0_prediction_turns_the_output_into_the_noise_in_every_sampler() {
    // The same weights as `model()`, read as an x0-predicting model.
    let mut cfg = tiny_config(Role::Short, 5, 2);
    cfg.diffusion.prediction_type = PredictionType::Sample;
    let m = model_of(&cfg, 21);
    let (l, n) = (7usize, 6 * 7);
    let observed = values(n, 31, 1.0);
    let mask = binary_mask(n, 32, 0.4);
    for sc in [
        SamplerConfig::ddpm(),
        SamplerConfig::ddim(4, 1.0),
        SamplerConfig::dpmpp2m(4),
    ] {
        // (that an x0 plan converts at every step and an epsilon plan at none is a unit test of the sampler)
        let plan = sc.plan(m.schedule(), VarianceType::FixedSmall).unwrap();
        let x0_plan = plan
            .clone()
            .for_prediction(PredictionType::Sample, m.schedule());
        assert_ne!(x0_plan, plan);
        assert_eq!(
            plan.clone()
                .for_prediction(PredictionType::Epsilon, m.schedule()),
            plan
        );
        let blocks = plan.num_noise_blocks();
        let noise = values(blocks * n, 33, 1.5);
        let obs = &Observation::new(&observed, &mask, [1, 6, l]).unwrap();
        let got = sample(
            &m,
            obs,
            1,
            &sc,
            Noise::Injected(&noise),
            &Control::default(),
        )
        .unwrap();
        // A hand loop over the public forward: eps = (x - a * out) * inv_s with a = sqrt(abar_t),
        // inv_s = 1 / sqrt(1 - abar_t) rounded from f64 (training.diffusion.predicted_noise), then the step.
        // The epsilon plan's sampler steps with the hand-converted noise (it converts nothing itself).
        let mut x = noise[..n].to_vec();
        let mut out = vec![0.0f32; n];
        let mut sampler = Sampler::new(&plan, n);
        while let Some(t) = sampler.timestep() {
            m.forward(
                &x,
                &Observation::new(&observed, &mask, [1, 6, l]).unwrap(),
                t,
                &mut out,
            )
            .unwrap();
            let ab = m.schedule().alpha_bar(Some(t));
            let (a, inv_s) = (ab.sqrt() as f32, (1.0 / (1.0 - ab).sqrt()) as f32);
            let mut eps: Vec<f32> = x
                .iter()
                .zip(&out)
                .map(|(xv, ov)| (xv - a * ov) * inv_s)
                .collect();
            let i = sampler.index();
            let z = if blocks > 1 {
                &noise[(i + 1) * n..(i + 2) * n]
            } else {
                &noise[..0]
            };
            sampler.step(&mut x, &mut eps, z).unwrap();
        }
        assert!(sampler.step(&mut x, &mut out, &[]).is_err()); // past the last step
        for j in 0..n {
            if mask[j] == 1.0 {
                x[j] = observed[j];
            }
        }
        assert_eq!(got, x, "{sc:?}");
        // the epsilon reading of the same weights gives another chain: the conversion ran
        let eps_chain = sample(
            model(),
            obs,
            1,
            &sc,
            Noise::Injected(&noise),
            &Control::default(),
        )
        .unwrap();
        assert_ne!(eps_chain, got, "{sc:?}");
    }
}
