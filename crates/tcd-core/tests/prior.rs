//! The prior forecaster: its weight file (one test per way it can be wrong), the shapes and checks of
//! `predict`, and its numbers against a naive f64 forward written from `PriorNet`'s formulas in their
//! PyTorch order (DCT, then fc_in, ...) on every kernel path this CPU supports.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::collections::BTreeMap;
use tcd_core::FileConfig;

use common::*;
use tcd_core::{
    dct_matrix, with_threads, Anchor, Control, DataConfig, Denoiser, Error, GapFill, Kernel,
    Network, Prior, PriorConfig, PriorModelConfig,
};

/// K = 6 (2 joints × 3), L = 12, chunk 4, 3 blocks: small, and with a horizon that is no multiple of
/// the chunk the rollout still crosses several chunks.
fn config() -> PriorConfig {
    PriorConfig {
        format_version: 1,
        role: "prior".into(),
        model: PriorModelConfig {
            num_joints: 2,
            coords: 3,
            num_features: 6,
            obs_len: 12,
            chunk: 4,
            blocks: 3,
            layer_norm_eps: 1e-5,
            anchor: Anchor::Last,
            gap_fill: GapFill::None,
            inbetween_context: 0,
            inbetween_max_gap: 0,
            joint_inbetween_context: 0,
            joint_inbetween_max_gap: 0,
        },
        data: DataConfig::default(),
    }
}

fn prior(seed: u64) -> (Prior, BTreeMap<String, RawTensor>) {
    let cfg = config();
    let t = prior_tensors(&cfg, seed);
    (
        Prior::from_bytes(&bytes(&cfg.to_json(), &t), "prior.safetensors").unwrap(),
        t,
    )
}

fn load_err(json: &str, t: &BTreeMap<String, RawTensor>) -> Error {
    Prior::from_bytes(&bytes(json, t), "p.safetensors").unwrap_err()
}

// ------------------------------------------------------------------------------- weight file

#[test]
fn good_file_loads_with_its_config() {
    let (p, _) = prior(1);
    assert_eq!(p.config(), &config());
    assert_eq!((p.num_features(), p.obs_len(), p.chunk()), (6, 12, 4));
    assert_eq!(p.path().to_str(), Some("prior.safetensors"));
    assert_eq!(p.dct(), dct_matrix(12).as_slice());
    assert_eq!(p.config_json(), config().to_json());
}

#[test]
fn missing_file_and_directory() {
    let dir = tempfile::tempdir().unwrap();
    assert!(matches!(
        Prior::load(dir.path().join("nope.safetensors")),
        Err(Error::NotFound { .. })
    ));
    assert!(matches!(
        Prior::load(dir.path()),
        Err(Error::NotAFile { .. })
    ));
    let (_, t) = prior(1);
    let p = write(
        dir.path(),
        "prior.safetensors",
        &bytes(&config().to_json(), &t),
    );
    assert_eq!(Prior::load(&p).unwrap().chunk(), 4);
}

#[test]
fn config_errors_name_the_field() {
    let cfg = config();
    let (_, t) = prior(1);
    let invalid =
        |json: String, field: &str| assert_eq!(invalid_field(load_err(&json, &t)), field, "{json}");
    invalid(
        with(&cfg, |v| v["format_version"] = 2.into()),
        "format_version",
    );
    invalid(
        with(&cfg, |v| v["model"]["num_features"] = 7.into()),
        "model.num_features",
    );
    invalid(
        with(&cfg, |v| v["model"]["chunk"] = 13.into()),
        "model.chunk",
    );
    invalid(
        with(&cfg, |v| v["model"]["chunk"] = 0.into()),
        "model.chunk",
    );
    invalid(
        with(&cfg, |v| v["model"]["blocks"] = 0.into()),
        "model.blocks",
    );
    invalid(
        with(&cfg, |v| v["model"]["layer_norm_eps"] = 0.0.into()),
        "model.layer_norm_eps",
    );
    invalid(
        with(&cfg, |v| v["model"]["layer_norm_eps"] = (-1e-5).into()),
        "model.layer_norm_eps",
    );
    // a denoiser's role: refused by name, pointing at the denoiser's loader
    let json = with(&cfg, |v| v["role"] = "short".into());
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::InvalidConfig { field, .. } if field == "role"),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("`Denoiser::load`")
            && e.to_string().contains("`tcd.engine.Denoiser.load`"),
        "{e}"
    );
    // a missing or mistyped field: the parser's message names it
    for (name, json) in [
        (
            "model",
            with(&cfg, |v| drop(v.as_object_mut().unwrap().remove("model"))),
        ),
        (
            "role",
            with(&cfg, |v| drop(v.as_object_mut().unwrap().remove("role"))),
        ),
        (
            "chunk",
            with(&cfg, |v| {
                drop(v["model"].as_object_mut().unwrap().remove("chunk"))
            }),
        ),
        (
            "obs_len",
            with(&cfg, |v| {
                drop(v["model"].as_object_mut().unwrap().remove("obs_len"))
            }),
        ),
        (
            "layer_norm_eps",
            with(&cfg, |v| {
                drop(v["model"].as_object_mut().unwrap().remove("layer_norm_eps"))
            }),
        ),
    ] {
        let e = load_err(&json, &t);
        assert!(matches!(e, Error::BadMetadata { .. }), "{name}: {e:?}");
        assert!(e.to_string().contains(name), "{name}: {e}");
    }
    let e = load_err(&with(&cfg, |v| v["model"]["blocks"] = "three".into()), &t);
    assert!(
        matches!(e, Error::BadMetadata { .. }) && e.to_string().contains("invalid type"),
        "{e}"
    );
    let e = Prior::from_bytes(&serialize(&t, None), "p").unwrap_err();
    assert!(matches!(e, Error::MissingMetadata { .. }), "{e:?}");
    // unknown keys are ignored
    let json = with(&cfg, |v| {
        v["training"] = serde_json::json!({"iteration": 3});
        v["model"]["future_field"] = 1.into();
    });
    assert_eq!(
        Prior::from_bytes(&bytes(&json, &t), "p").unwrap().config(),
        &cfg
    );
}

#[test]
fn tensor_errors_name_the_tensor() {
    let cfg = config();
    let json = cfg.to_json();
    let (_, good) = prior(1);

    let mut t = good.clone();
    t.remove("blocks.2.norm_bias");
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::MissingTensor { name, expected, .. } if name == "blocks.2.norm_bias" && expected == &vec![6]),
        "{e:?}"
    );

    let mut t = good.clone();
    t.insert(
        "blocks.3.fc.bias".into(),
        RawTensor::f32(vec![12], &[0.0; 12]),
    );
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::UnexpectedTensor { name, .. } if name == "blocks.3.fc.bias"),
        "{e:?}"
    );

    let mut t = good.clone();
    t.insert(
        "blocks.0.fc.weight".into(),
        RawTensor::f32(vec![12, 11], &[0.0; 132]),
    );
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::TensorShape { name, expected, received, .. }
                     if name == "blocks.0.fc.weight" && expected == &vec![12, 12] && received == &vec![12, 11]),
        "{e:?}"
    );

    let mut t = good.clone();
    let mut w = t["fc_out.weight"].values();
    w[5] = f32::NAN;
    t.insert("fc_out.weight".into(), RawTensor::f32(vec![6, 6], &w));
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::NonFiniteTensor { name, index: 5, .. } if name == "fc_out.weight"),
        "{e:?}"
    );

    let mut t = good.clone();
    t.insert(
        "fc_in.bias".into(),
        RawTensor {
            dtype: safetensors::Dtype::F64,
            shape: vec![6],
            bytes: vec![0; 48],
        },
    );
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::TensorDtype { name, .. } if name == "fc_in.bias"),
        "{e:?}"
    );

    let e = Prior::from_bytes(&bytes(&json, &good)[..100], "p").unwrap_err();
    assert!(matches!(e, Error::Corrupt { .. }), "{e:?}");
    assert!(e.is_weights_error());
}

#[test]
fn a_prior_file_is_no_denoiser() {
    let (_, t) = prior(1);
    let e = Denoiser::from_bytes(&bytes(&config().to_json(), &t), "prior.safetensors").unwrap_err();
    assert!(
        matches!(&e, Error::InvalidConfig { field, .. } if field == "role"),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("`Prior::load`")
            && e.to_string().contains("`tcd.engine.Prior.load`"),
        "{e}"
    );
}

// ------------------------------------------------------------------------------- the DCT

#[test]
fn dct_is_orthonormal_with_the_cosines_of_training_prior() {
    for n in [1usize, 2, 12, 50] {
        let d = dct_matrix(n);
        for a in 0..n {
            for b in 0..n {
                let dot: f64 = (0..n)
                    .map(|i| d[a * n + i] as f64 * d[b * n + i] as f64)
                    .sum();
                assert!(
                    (dot - f64::from(u8::from(a == b))).abs() < 1e-6,
                    "n={n} ({a}, {b}): {dot}"
                );
            }
        }
    }
    // row 0 is the constant 1/sqrt(n); row 1 of n = 2 is (1, -1)/sqrt(2)
    assert!(dct_matrix(50)[..50]
        .iter()
        .all(|&v| v == (1.0f64 / 50f64.sqrt()) as f32));
    let d2 = dct_matrix(2);
    assert!(
        (d2[2] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-7
            && (d2[3] + std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-7
    );
}

// ------------------------------------------------------------------------------- predict

/// `PriorNet.rollout` in f64 from the PyTorch formulas, in their order: DCT, fc_in, blocks, fc_out,
/// inverse DCT (first chunk), + last pose. obs (B, T, K) → (B, horizon, K).
fn naive_rollout(
    cfg: &PriorModelConfig,
    t: &BTreeMap<String, RawTensor>,
    obs: &[f32],
    b: usize,
    frames: usize,
    horizon: usize,
) -> Vec<f64> {
    let (k, l, c) = (cfg.num_features, cfg.obs_len, cfg.chunk);
    let g = |name: &str| get(t, name);
    let d = naive_dct(l);
    let forward = |hist: &[f64]| -> Vec<f64> {
        // hist (L, K) → x (K, L) DCT coefficients
        let mut x = vec![0.0; k * l];
        for kk in 0..k {
            for f in 0..l {
                x[kk * l + f] = (0..l).map(|j| hist[j * k + kk] * d[f * l + j]).sum();
            }
        }
        let spatial = |x: &[f64], w: &[f64], bias: &[f64]| -> Vec<f64> {
            let mut y = vec![0.0; k * l];
            for o in 0..k {
                for f in 0..l {
                    y[o * l + f] =
                        bias[o] + (0..k).map(|i| w[o * k + i] * x[i * l + f]).sum::<f64>();
                }
            }
            y
        };
        x = spatial(&x, &g("fc_in.weight"), &g("fc_in.bias"));
        for i in 0..cfg.blocks {
            let (w, bias) = (
                g(&format!("blocks.{i}.fc.weight")),
                g(&format!("blocks.{i}.fc.bias")),
            );
            let (nw, nb) = (
                g(&format!("blocks.{i}.norm_weight")),
                g(&format!("blocks.{i}.norm_bias")),
            );
            let mut y = vec![0.0; k * l];
            for kk in 0..k {
                for o in 0..l {
                    y[kk * l + o] =
                        bias[o] + (0..l).map(|f| w[o * l + f] * x[kk * l + f]).sum::<f64>();
                }
            }
            for f in 0..l {
                let mean = (0..k).map(|kk| y[kk * l + f]).sum::<f64>() / k as f64;
                let var = (0..k).map(|kk| (y[kk * l + f] - mean).powi(2)).sum::<f64>() / k as f64;
                let rstd = 1.0 / (var + cfg.layer_norm_eps).sqrt();
                for kk in 0..k {
                    x[kk * l + f] += (y[kk * l + f] - mean) * rstd * nw[kk] + nb[kk];
                }
            }
        }
        x = spatial(&x, &g("fc_out.weight"), &g("fc_out.bias"));
        let mut out = vec![0.0; c * k];
        for tt in 0..c {
            // the anchor: the last pose, or (a repair fill) the input frame itself
            let base = match cfg.anchor {
                Anchor::Last => l - 1,
                Anchor::Window => tt,
            };
            for kk in 0..k {
                out[tt * k + kk] = hist[base * k + kk]
                    + (0..l).map(|f| x[kk * l + f] * d[f * l + tt]).sum::<f64>();
            }
        }
        out
    };
    let mut all = Vec::with_capacity(b * horizon * k);
    for s in 0..b {
        let seq = &obs[s * frames * k..(s + 1) * frames * k];
        let mut hist: Vec<f64> = seq[(frames - l) * k..].iter().map(|&v| v as f64).collect();
        let mut out = Vec::new();
        while out.len() < horizon * k {
            let p = forward(&hist);
            out.extend_from_slice(&p);
            hist.drain(..c * k);
            hist.extend_from_slice(&p);
        }
        all.extend_from_slice(&out[..horizon * k]);
    }
    all
}

fn motion(b: usize, frames: usize, k: usize, seed: u64) -> Vec<f32> {
    values(b * frames * k, seed, 0.5)
}

#[test]
fn predict_matches_the_f64_reference_on_every_kernel() {
    let cfg = config();
    let (p, t) = prior(7);
    let (b, frames) = (5, 15);
    let obs = motion(b, frames, 6, 3);
    for horizon in [1usize, 4, 10, 13] {
        let want = naive_rollout(&cfg.model, &t, &obs, b, frames, horizon);
        // the network's contribution (prediction − last pose) is large against the tolerance
        let contribution = (0..b * horizon * 6)
            .map(|i| {
                (want[i] - obs[(i / (horizon * 6)) * frames * 6 + (frames - 1) * 6 + i % 6] as f64)
                    .abs()
            })
            .fold(0.0, f64::max);
        assert!(contribution > 0.5, "contribution {contribution}");
        for kernel in Kernel::supported() {
            let pk = p.clone().with_kernel(kernel).unwrap();
            assert_eq!(pk.kernel(), kernel);
            let got = pk
                .predict(&obs, b, frames, horizon, &Control::default())
                .unwrap();
            assert_eq!(got.len(), b * horizon * 6);
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let err = max_abs_diff(&got, &want);
            assert!(
                err <= 1e-5 * scale.max(1.0),
                "{kernel} horizon {horizon}: max abs diff {err}, scale {scale}"
            );
        }
    }
}

#[test]
fn a_repair_fill_corrects_its_window_on_every_kernel() {
    // anchor "window": the output is the network's added to the input window itself, frame by frame
    let mut cfg = config();
    cfg.model.chunk = cfg.model.obs_len;
    cfg.model.anchor = Anchor::Window;
    let t = prior_tensors(&cfg, 8);
    let p = Prior::from_bytes(&bytes(&cfg.to_json(), &t), "repair_fill.safetensors").unwrap();
    let (b, l, k) = (4, 12, 6);
    let obs = motion(b, l, k, 10);
    let want = naive_rollout(&cfg.model, &t, &obs, b, l, l);
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for kernel in Kernel::supported() {
        let got = p
            .clone()
            .with_kernel(kernel)
            .unwrap()
            .predict(&obs, b, l, l, &Control::default())
            .unwrap();
        let err = max_abs_diff(&got, &want);
        assert!(err <= 1e-5 * scale.max(1.0), "{kernel}: max abs diff {err}");
    }
    // the same weights anchored on the last pose differ by exactly the anchor
    let mut last = cfg.clone();
    last.model.anchor = Anchor::Last;
    let forecast = naive_rollout(&last.model, &t, &obs, b, l, l);
    let (s, tt, kk) = (1, 3, 2);
    let i = (s * l + tt) * k + kk;
    let shift = obs[i] as f64 - obs[(s * l + l - 1) * k + kk] as f64;
    assert!((want[i] - forecast[i] - shift).abs() < 1e-9 && shift.abs() > 1e-3);
    // it corrects a window, it does not forecast: another horizon is refused naming it
    let e = p.predict(&obs, b, l, 1, &Control::default()).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput { argument, .. } if argument == "horizon"),
        "{e:?}"
    );
    // and its chunk must be its obs_len
    invalid_chunk_for_window(&cfg, &t);
    // gap_fill: "forecaster" parses for it (and is written back), is refused for a forecaster, and an
    // unknown value is refused naming the field
    let gaps = with(&cfg, |v| v["model"]["gap_fill"] = "forecaster".into());
    let g = Prior::from_bytes(&bytes(&gaps, &t), "repair_fill.safetensors").unwrap();
    assert_eq!(g.config().model.gap_fill, GapFill::Forecaster);
    assert!(g.config().to_json().contains("\"gap_fill\":\"forecaster\""));
    assert!(!p.config().to_json().contains("gap_fill"));
    let on_last = with(&last, |v| v["model"]["gap_fill"] = "forecaster".into());
    assert_eq!(
        invalid_field(Prior::from_bytes(&bytes(&on_last, &t), "p.safetensors").unwrap_err()),
        "model.gap_fill"
    );
    // an in-betweener (inbetween_context, inbetween_max_gap; kernels inbetween_1 ..) loads on a gap-filling
    // fill, one kernel per gap length, and is written back; without the gap fill, with one of the two keys 0,
    // or with a gap as long as the window it is refused naming the field, and a missing kernel is refused
    let mut ib = g.config().clone();
    (ib.model.inbetween_context, ib.model.inbetween_max_gap) = (2, 3);
    let ib_t = prior_tensors(&ib, 9);
    let q = Prior::from_bytes(&bytes(&ib.to_json(), &ib_t), "repair_fill.safetensors").unwrap();
    assert_eq!(
        q.inbetween_kernel(3).map(<[f32]>::len),
        Some(3 * tcd_core::inbetween_width(3, 2))
    );
    assert_eq!(tcd_core::inbetween_width(3, 2), 3 * 7 + 2);
    assert!(q.inbetween_kernel(0).is_none() && q.inbetween_kernel(4).is_none());
    assert!(q.config().to_json().contains("\"inbetween_max_gap\":3"));
    for edit in [
        (|v: &mut serde_json::Value| v["model"]["gap_fill"] = "none".into())
            as fn(&mut serde_json::Value),
        |v| v["model"]["inbetween_context"] = 0.into(),
        |v| v["model"]["inbetween_max_gap"] = 12.into(),
    ] {
        assert_eq!(
            invalid_field(
                Prior::from_bytes(&bytes(&with(&ib, edit), &ib_t), "p.safetensors").unwrap_err()
            ),
            "model.inbetween_max_gap"
        );
    }
    // the joint in-betweener (joint_inbetween_context, joint_inbetween_max_gap; joint_inbetween_1 ..) loads on
    // any repair fill and is refused on a forecaster or without its context
    let mut jb = p.config().clone();
    (
        jb.model.joint_inbetween_context,
        jb.model.joint_inbetween_max_gap,
    ) = (3, 2);
    let jb_t = prior_tensors(&jb, 10);
    let j = Prior::from_bytes(&bytes(&jb.to_json(), &jb_t), "repair_fill.safetensors").unwrap();
    assert_eq!(
        j.joint_inbetween_kernel(2).map(<[f32]>::len),
        Some(2 * tcd_core::inbetween_width(2, 3))
    );
    assert!(j.inbetween_kernel(1).is_none() && j.joint_inbetween_kernel(3).is_none());
    for edit in [
        (|v: &mut serde_json::Value| v["model"]["anchor"] = "last".into())
            as fn(&mut serde_json::Value),
        |v| v["model"]["joint_inbetween_context"] = 0.into(),
    ] {
        let field = invalid_field(
            Prior::from_bytes(&bytes(&with(&jb, edit), &jb_t), "p.safetensors").unwrap_err(),
        );
        assert!(field.starts_with("model."), "{field}");
    }
    let mut short = ib_t.clone();
    short.remove("inbetween_2");
    let e = Prior::from_bytes(&bytes(&ib.to_json(), &short), "p.safetensors").unwrap_err();
    assert!(e.to_string().contains("inbetween_2"), "{e}");
    let unknown = with(&cfg, |v| v["model"]["gap_fill"] = "linear".into());
    let e = Prior::from_bytes(&bytes(&unknown, &t), "p.safetensors").unwrap_err();
    assert!(
        e.to_string()
            .contains("model.gap_fill: unknown variant `linear`, expected `none` or `forecaster`"),
        "{e}"
    );
}

fn invalid_chunk_for_window(cfg: &PriorConfig, t: &BTreeMap<String, RawTensor>) {
    let json = with(cfg, |v| v["model"]["chunk"] = 4.into());
    assert_eq!(
        invalid_field(Prior::from_bytes(&bytes(&json, t), "p.safetensors").unwrap_err()),
        "model.chunk"
    );
}

#[test]
fn rollout_appends_each_chunk_and_forward_is_its_first() {
    let (p, _) = prior(2);
    let (b, l, k, c) = (3, 12, 6, 4);
    let obs = motion(b, l, k, 9);
    let first = p.forward(&obs, b).unwrap();
    let long = p
        .predict(&obs, b, l, 2 * c + 1, &Control::default())
        .unwrap();
    for s in 0..b {
        let seq_first = &first[s * c * k..(s + 1) * c * k];
        assert_eq!(&long[s * (2 * c + 1) * k..][..c * k], seq_first);
        // the second chunk is the forward of the shifted history
        let mut hist = obs[s * l * k + c * k..(s + 1) * l * k].to_vec();
        hist.extend_from_slice(seq_first);
        let second = p.forward(&hist, 1).unwrap();
        assert_eq!(
            &long[s * (2 * c + 1) * k + c * k..][..c * k],
            second.as_slice()
        );
    }
    // more frames than obs_len: only the last obs_len are read (NaN before them is fine)
    let mut longer = vec![f32::NAN; b * 20 * k];
    for s in 0..b {
        longer[(s * 20 + 8) * k..(s + 1) * 20 * k]
            .copy_from_slice(&obs[s * l * k..(s + 1) * l * k]);
    }
    assert_eq!(
        p.predict(&longer, b, 20, c, &Control::default()).unwrap(),
        first
    );
}

#[test]
fn results_do_not_depend_on_threads_or_batch_neighbours() {
    let (p, _) = prior(4);
    let (b, frames, k, h) = (11, 12, 6, 9);
    let obs = motion(b, frames, k, 5);
    let one = with_threads(Some(1), || {
        p.predict(&obs, b, frames, h, &Control::default())
    })
    .unwrap()
    .unwrap();
    for threads in [2, 3, 7] {
        let many = with_threads(Some(threads), || {
            p.predict(&obs, b, frames, h, &Control::default())
        })
        .unwrap()
        .unwrap();
        assert_eq!(one, many, "{threads} threads");
    }
    for s in [0, 6, 10] {
        let alone = p
            .predict(
                &obs[s * frames * k..(s + 1) * frames * k],
                1,
                frames,
                h,
                &Control::default(),
            )
            .unwrap();
        assert_eq!(
            alone.as_slice(),
            &one[s * h * k..(s + 1) * h * k],
            "sequence {s}"
        );
    }
}

#[test]
fn bad_arguments_are_named() {
    let (p, _) = prior(1);
    let c = Control::default();
    let obs = motion(2, 12, 6, 1);
    assert_eq!(invalid_argument(p.predict(&obs, 0, 12, 4, &c)), "batch");
    assert_eq!(invalid_argument(p.predict(&obs, 2, 12, 0, &c)), "horizon");
    assert_eq!(
        invalid_argument(p.predict(&obs[..2 * 11 * 6], 2, 11, 4, &c)),
        "obs"
    );
    assert_eq!(
        invalid_argument(p.predict(&obs[..100], 2, 12, 4, &c)),
        "obs"
    );
    assert_eq!(
        invalid_argument(p.predict(&obs, 2, 12, usize::MAX / 4, &c)),
        "horizon"
    );
    let mut bad = obs.clone();
    bad[12 * 6 + 7] = f32::INFINITY;
    let e = p.predict(&bad, 2, 12, 4, &c).unwrap_err();
    assert!(
        e.to_string()
            .contains(&format!("at flat index {}", 12 * 6 + 7)),
        "{e}"
    );
    let cancelled = Control::default();
    cancelled.cancel();
    assert!(matches!(
        p.predict(&obs, 2, 12, 4, &cancelled),
        Err(Error::Cancelled)
    ));
}
