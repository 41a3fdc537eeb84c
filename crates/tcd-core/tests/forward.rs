//! The denoiser forward: against a naive f64 reference, determinism, batching, input errors.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use tcd_core::FileConfig;
use tcd_core::{Error, Network, Observation, Role, Workspace};

#[test]
fn matches_naive_reference() {
    for (obs, pred) in [(8usize, 2usize), (3, 0)] {
        let (model, tensors) = tiny_model(Role::Short, obs, pred, 11);
        let (b, k, l) = (2usize, 6usize, obs + pred);
        let n = b * k * l;
        let noisy = values(n, 1, 1.5);
        let observed = values(n, 2, 0.8);
        let mask = binary_mask(n, 3, 0.5);
        for step in [0usize, 4, 9] {
            let mut out = vec![0.0f32; n];
            model
                .forward(
                    &noisy,
                    &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
                    step,
                    &mut out,
                )
                .unwrap();
            let want = naive_forward(
                model.config(),
                &tensors,
                &noisy,
                &observed,
                &mask,
                (b, l),
                step,
            );
            let scale = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = max_abs_diff(&out, &want);
            eprintln!("L={l} step={step}: err {err:e} scale {scale}");
            assert!(scale > 1e-2, "output is trivially small: {scale}");
            assert!(
                err < 1e-5 * scale.max(1.0),
                "L={l} step={step}: max abs err {err} (scale {scale})"
            );
        }
    }
}

#[test]
fn length_one_skips_the_time_transformer() {
    let (model, tensors) = tiny_model(Role::Short, 1, 0, 5);
    let (b, l) = (1usize, 1usize);
    let n = 6;
    let (noisy, observed, mask) = (values(n, 1, 1.0), values(n, 2, 1.0), binary_mask(n, 3, 0.5));
    let mut out = vec![0.0f32; n];
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
            3,
            &mut out,
        )
        .unwrap();
    let want = naive_forward(
        model.config(),
        &tensors,
        &noisy,
        &observed,
        &mask,
        (b, l),
        3,
    );
    assert!(max_abs_diff(&out, &want) < 1e-5);
}

#[test]
fn finite_deterministic_and_batch_independent() {
    let (model, _) = tiny_model(Role::Long, 10, 4, 2);
    let (b, k, l) = (3usize, 6usize, 14usize);
    let n = k * l;
    let noisy = values(b * n, 4, 2.0);
    let observed = values(b * n, 5, 1.0);
    let mask = binary_mask(b * n, 6, 0.3);
    let mut out1 = vec![0.0f32; b * n];
    let mut out2 = vec![0.0f32; b * n];
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
            7,
            &mut out1,
        )
        .unwrap();
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
            7,
            &mut out2,
        )
        .unwrap();
    assert!(out1.iter().all(|v| v.is_finite()));
    assert_eq!(out1, out2);
    // each sequence alone gives the same bits
    for i in 0..b {
        let r = i * n..(i + 1) * n;
        let mut one = vec![0.0f32; n];
        model
            .forward(
                &noisy[r.clone()],
                &Observation::new(&observed[r.clone()], &mask[r.clone()], [1, k, l]).unwrap(),
                7,
                &mut one,
            )
            .unwrap();
        assert_eq!(&out1[r], one.as_slice());
    }
    // prepared + workspace reuse across steps give the same bits as the plain forward
    let obs = Observation::new(&observed, &mask, [b, k, l]).unwrap();
    let prepared = model.prepare(&obs).unwrap();
    let mut ws = Workspace::new(&model, 5); // wrong length: gets rebuilt
    for step in [7usize, 0, 7] {
        let mut a = vec![0.0f32; b * n];
        let mut c = vec![0.0f32; b * n];
        model
            .forward_with_workspace(&prepared, &mut ws, &noisy, step, &mut a)
            .unwrap();
        model.forward(&noisy, &obs, step, &mut c).unwrap();
        assert_eq!(a, c);
        let mut d = vec![0.0f32; b * n];
        model
            .forward_prepared(&prepared, &noisy, step, &mut d)
            .unwrap();
        assert_eq!(a, d);
    }
    assert_eq!(ws.length(), l);
    // different steps give different outputs
    let mut o0 = vec![0.0f32; b * n];
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [b, 6, l]).unwrap(),
            0,
            &mut o0,
        )
        .unwrap();
    assert_ne!(o0, out1);
}

#[test]
fn ignored_entries_may_be_nan() {
    let (model, _) = tiny_model(Role::Short, 8, 2, 3);
    let n = 6 * 10;
    let mut noisy = values(n, 1, 1.0);
    let mut observed = values(n, 2, 1.0);
    let mask = binary_mask(n, 3, 0.5);
    let mut base = vec![0.0f32; n];
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [1, 6, 10]).unwrap(),
            2,
            &mut base,
        )
        .unwrap();
    for i in 0..n {
        if mask[i] == 1.0 {
            noisy[i] = f32::NAN;
        } else {
            observed[i] = f32::NAN;
        }
    }
    let mut out = vec![0.0f32; n];
    model
        .forward(
            &noisy,
            &Observation::new(&observed, &mask, [1, 6, 10]).unwrap(),
            2,
            &mut out,
        )
        .unwrap();
    assert_eq!(base, out);
}

#[test]
fn input_errors_name_the_argument() {
    let (model, _) = tiny_model(Role::Short, 8, 2, 3);
    let n = 6 * 10;
    let ok = values(n, 1, 1.0);
    let mask = binary_mask(n, 3, 0.5);
    let mut out = vec![0.0f32; n];
    let arg = |e: Error| match e {
        Error::InvalidInput { argument, .. } => argument,
        other => panic!("{other:?}"),
    };
    // the observation's own errors, when it is made
    let observation =
        |v: &[f32], m: &[f32], shape| Observation::new(v, m, shape).map(drop).map_err(arg);
    assert_eq!(
        observation(&ok[1..], &mask, [1, 6, 10]).unwrap_err(),
        "observed"
    );
    assert_eq!(
        observation(&ok, &mask[1..], [1, 6, 10]).unwrap_err(),
        "mask"
    );
    assert_eq!(observation(&ok, &mask, [0, 6, 10]).unwrap_err(), "batch");
    assert_eq!(observation(&ok, &mask, [1, 6, 0]).unwrap_err(), "length");
    let mut soft = mask.clone();
    soft[4] = 0.5;
    let e = Observation::new(&ok, &soft, [1, 6, 10]).unwrap_err();
    assert!(e.to_string().contains("0.5 at flat index 4"), "{e}");
    let mut bad = ok.clone();
    let i = mask.iter().position(|&m| m == 1.0).unwrap();
    bad[i] = f32::INFINITY;
    assert_eq!(
        observation(&bad, &mask, [1, 6, 10]).unwrap_err(),
        "observed"
    );
    // the forward's
    let obs = Observation::new(&ok, &mask, [1, 6, 10]).unwrap();
    assert_eq!(
        arg(model.forward(&ok[1..], &obs, 0, &mut out).unwrap_err()),
        "noisy"
    );
    assert_eq!(
        arg(model.forward(&ok, &obs, 0, &mut out[1..]).unwrap_err()),
        "out"
    );
    assert_eq!(
        arg(model.forward(&ok, &obs, 10, &mut out).unwrap_err()),
        "step"
    );
    // an observation of another K
    let other_k = Observation::new(&ok, &mask, [2, 3, 10]).unwrap();
    let e = model.forward(&ok, &other_k, 0, &mut out).unwrap_err();
    assert!(
        e.to_string().contains("K = 6 (the model's num_features)"),
        "{e}"
    );
    assert_eq!(arg(e), "observed");
    let e = model.forward(&ok, &obs, 12, &mut out).unwrap_err();
    assert_eq!(
        e.to_string(),
        "Argument `step` must be a diffusion step in 0..10 (num_train_timesteps = 10), but received 12."
    );
}

#[test]
fn prepared_and_workspace_from_another_model() {
    let (a, _) = tiny_model(Role::Short, 8, 2, 3);
    let mut cfg = tiny_config(Role::Short, 8, 2);
    cfg.model.channels = 8;
    cfg.model.num_layers = 3;
    let t = random_tensors(&cfg, 4);
    let b = tcd_core::Denoiser::from_bytes(&serialize(&t, Some(cfg.to_json())), "b").unwrap();
    let n = 6 * 10;
    let (x, mask) = (values(n, 1, 1.0), binary_mask(n, 2, 0.5));
    let mut out = vec![0.0f32; n];
    let obs = Observation::new(&x, &mask, [1, 6, 10]).unwrap();
    let pa = a.prepare(&obs).unwrap();
    let e = b.forward_prepared(&pa, &x, 0, &mut out).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput { argument, .. } if argument == "prepared"),
        "{e:?}"
    );
    // a workspace made for another model is rebuilt, not misused
    let mut ws = Workspace::new(&a, 10);
    let pb = b.prepare(&obs).unwrap();
    b.forward_with_workspace(&pb, &mut ws, &x, 0, &mut out)
        .unwrap();
    let mut want = vec![0.0f32; n];
    b.forward(&x, &obs, 0, &mut want).unwrap();
    assert_eq!(out, want);
}

#[test]
fn models_are_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<tcd_core::Denoiser>();
    check::<tcd_core::Prepared>();
}
