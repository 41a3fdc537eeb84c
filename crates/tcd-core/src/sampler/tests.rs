//! The samplers' unit tests: the timestep lists against diffusers', the x₀-to-noise conversion, a sampler's multistep
//! state, the plans.

use super::*;

#[test]
fn spacing_reference_lists() {
    let tr = |n| timesteps(50, n, TimestepSpacing::Trailing).unwrap();
    let le = |n| timesteps(50, n, TimestepSpacing::Leading).unwrap();
    let li = |n| timesteps(50, n, TimestepSpacing::Linspace).unwrap();
    assert_eq!(tr(5), vec![49, 39, 29, 19, 9]);
    assert_eq!(le(5), vec![40, 30, 20, 10, 0]);
    assert_eq!(li(5), vec![49, 37, 24, 12, 0]);
    // numpy: np.round(np.arange(50, 0, -12.5)) - 1 -> [49, 37, 24, 11] (half to even)
    assert_eq!(tr(4), vec![49, 37, 24, 11]);
    assert_eq!(tr(3), vec![49, 32, 16]);
    assert_eq!(tr(1), vec![49]);
    assert_eq!(le(1), vec![0]);
    assert_eq!(li(1), vec![0]);
    let all: Vec<usize> = (0..50).rev().collect();
    for sp in [
        TimestepSpacing::Leading,
        TimestepSpacing::Trailing,
        TimestepSpacing::Linspace,
    ] {
        assert_eq!(timesteps(50, 50, sp).unwrap(), all);
        for n in 1..=50 {
            let ts = timesteps(50, n, sp).unwrap();
            assert_eq!(ts.len(), n);
            assert!(ts.windows(2).all(|w| w[0] > w[1]), "{sp:?} n={n}: {ts:?}");
            assert!(ts[0] < 50);
        }
    }
}

#[test]
fn spacing_errors_name_the_argument() {
    for n in [0, 51] {
        let e = timesteps(50, n, TimestepSpacing::Trailing).unwrap_err();
        assert!(e.to_string().contains("num_inference_steps"), "{e}");
    }
    let e = "middle".parse::<TimestepSpacing>().unwrap_err();
    assert!(e.to_string().contains("timestep_spacing"));
    assert_eq!(
        "linspace".parse::<TimestepSpacing>().unwrap(),
        TimestepSpacing::Linspace
    );
}

#[test]
fn sample_to_noise_recovers_the_noise_of_an_exact_x0() {
    // x_t = sqrt(abar) x0 + sqrt(1 - abar) eps: given the exact x0 the conversion returns eps.
    let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(50, 0.5));
    for t in [0, 1, 17, 49] {
        let c = SampleToNoise::new(&s, t);
        let ab = s.alpha_bar(Some(t));
        assert_eq!(c.a, ab.sqrt() as f32);
        assert_eq!(c.inv_s, (1.0 / (1.0 - ab).sqrt()) as f32);
        let (x0, eps) = ([0.3f64, -1.2, 2.5], [0.7f64, -0.4, 1.9]);
        let x: Vec<f32> = x0
            .iter()
            .zip(&eps)
            .map(|(a, e)| (ab.sqrt() * a + (1.0 - ab).sqrt() * e) as f32)
            .collect();
        let mut out: Vec<f32> = x0.iter().map(|&v| v as f32).collect();
        c.apply(&x, &mut out);
        for (got, want) in out.iter().zip(&eps) {
            // f32 rounding of x amplified by inv_s (up to 1 / sqrt(1 - abar_0), about 1e2 at t = 0)
            assert!(
                (*got as f64 - want).abs() < 1e-6 * c.inv_s as f64 * 4.0,
                "t={t}: {got} vs {want}"
            );
        }
    }
}

#[test]
fn a_sampler_keeps_its_multistep_state_and_resets_for_a_new_chain() {
    // A stand-in network (ε̂ a fixed function of x): a reset sampler repeats a fresh one's chain bit
    // for bit, and the second-order steps do read the state (a sampler whose state is cleared before
    // every step takes another chain).
    let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(50, 0.5));
    let plan = SamplerConfig::dpmpp2m(6)
        .plan(&s, VarianceType::FixedSmall)
        .unwrap();
    let net = |x: &[f32]| -> Vec<f32> { x.iter().map(|v| 0.5 * v.sin() - 0.1).collect() };
    let run = |sampler: &mut Sampler<'_>, forget: bool| {
        let mut x = vec![0.3f32, -1.1, 2.0, 0.7];
        while sampler.timestep().is_some() {
            let mut eps = net(&x);
            if forget {
                let next = sampler.index();
                sampler.reset();
                sampler.next = next;
            }
            sampler.step(&mut x, &mut eps, &[]).unwrap();
        }
        x
    };
    let mut sampler = Sampler::new(&plan, 4);
    let first = run(&mut sampler, false);
    assert!(sampler.step(&mut [0.0; 4], &mut [0.0; 4], &[]).is_err());
    sampler.reset();
    assert_eq!(sampler.timestep(), Some(plan.steps[0].t));
    assert_eq!(run(&mut sampler, false), first);
    assert_eq!(run(&mut Sampler::new(&plan, 4), false), first);
    assert_ne!(run(&mut Sampler::new(&plan, 4), true), first);
    // a buffer of the wrong size is refused, naming it
    let mut fresh = Sampler::new(&plan, 4);
    let e = fresh.step(&mut [0.0; 3], &mut [0.0; 4], &[]).unwrap_err();
    assert!(e.to_string().contains("`x`"), "{e}");
    assert_eq!(fresh.index(), 0);
}

#[test]
fn an_x0_plan_converts_the_output_at_every_step_and_an_epsilon_plan_at_none() {
    let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(10, 0.5));
    for sc in [
        SamplerConfig::ddpm(),
        SamplerConfig::ddim(4, 1.0),
        SamplerConfig::dpmpp2m(4),
    ] {
        let plan = sc.plan(&s, VarianceType::FixedSmall).unwrap();
        assert!(plan.steps.iter().all(|st| st.to_noise.is_none()));
        let x0_plan = plan.clone().for_prediction(PredictionType::Sample, &s);
        assert!(x0_plan
            .steps
            .iter()
            .all(|st| st.to_noise == Some(SampleToNoise::new(&s, st.t))));
        assert_eq!(
            plan.clone().for_prediction(PredictionType::Epsilon, &s),
            plan
        );
    }
}

#[test]
fn pairs_end_with_none() {
    assert_eq!(
        step_pairs(&[9, 4, 0]),
        vec![(9, Some(4)), (4, Some(0)), (0, None)]
    );
}
