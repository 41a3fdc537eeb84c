//! The MLP sample generator: its weight file (the ways it can be wrong, and the other kinds' files
//! refused by role both ways), the checks of `sample`, and its numbers against a naive f64 forward
//! written from `training/generator.py`'s formulas on every kernel path this CPU supports; seeded
//! noise independent of the thread count and of the batch.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::collections::BTreeMap;
use tcd_core::FileConfig;

use common::*;
use tcd_core::{
    seeded_noise, stage, with_threads, Control, DataConfig, Denoiser, Error, Generator,
    GeneratorConfig, GeneratorModelConfig, Kernel, Network, Noise, Prior, Sequences,
};

/// K = 6 (2 joints × 3), O = 5, P = 12 with C = 4 coefficients, 3 hidden layers of 24, z_dim 7: the
/// first layer reads (5 + 4) · 6 + 7 = 61 values.
fn config() -> GeneratorConfig {
    GeneratorConfig {
        format_version: 1,
        role: "generator".into(),
        model: GeneratorModelConfig {
            num_joints: 2,
            coords: 3,
            num_features: 6,
            obs_len: 5,
            pred_len: 12,
            hidden: 24,
            layers: 3,
            z_dim: 7,
            coefs: 4,
        },
        data: DataConfig::default(),
    }
}

/// Seeded uniform weights of about unit gain (biases ±0.3): the MLP's residual is large.
fn tensors(cfg: &GeneratorConfig, seed: u64) -> BTreeMap<String, RawTensor> {
    uniform_tensors(Generator::tensor_shapes(cfg.clone()).unwrap(), 6.0, seed)
}

fn generator(seed: u64) -> (Generator, BTreeMap<String, RawTensor>) {
    let cfg = config();
    let t = tensors(&cfg, seed);
    (
        Generator::from_bytes(&bytes(&cfg.to_json(), &t), "generator.safetensors").unwrap(),
        t,
    )
}

fn load_err(json: &str, t: &BTreeMap<String, RawTensor>) -> Error {
    Generator::from_bytes(&bytes(json, t), "g.safetensors").unwrap_err()
}

// ------------------------------------------------------------------------------- weight file

#[test]
fn good_file_loads_with_its_config() {
    let (g, _) = generator(1);
    assert_eq!(g.config(), &config());
    assert_eq!(
        (
            g.num_features(),
            g.obs_len(),
            g.pred_len(),
            g.coefs(),
            g.z_dim(),
            g.hidden(),
            g.layers()
        ),
        (6, 5, 12, 4, 7, 24, 3)
    );
    assert_eq!(g.path().to_str(), Some("generator.safetensors"));
    assert_eq!(g.config_json(), config().to_json());
    assert_eq!(config().model.input_width(), Some(61));
    let names: Vec<String> = Generator::tensor_shapes(config())
        .unwrap()
        .into_iter()
        .map(|(n, s)| format!("{n}{s:?}"))
        .collect();
    assert_eq!(
        names,
        [
            "layers.0.weight[24, 61]",
            "layers.0.bias[24]",
            "layers.1.weight[24, 24]",
            "layers.1.bias[24]",
            "layers.2.weight[24, 24]",
            "layers.2.bias[24]",
            "head.weight[24, 24]",
            "head.bias[24]"
        ]
    );
    // training/generator.py's keys beside the config's: `training`, `source_revision`, and a `data` block
    // of any keys, kept in config_json as stored
    let (_, t) = generator(1);
    let json = with(&config(), |v| {
        v["training"] = serde_json::json!({"description": "IMLE", "steps": 7149});
        v["source_revision"] = "abc123".into();
        v["data"] = serde_json::json!({"dataset": "humaneva", "fps": 60.0, "layout": "humaneva15"});
    });
    let g = Generator::from_bytes(&bytes(&json, &t), "g").unwrap();
    assert_eq!(g.config().model, config().model);
    assert_eq!(g.config().data.dataset.as_deref(), Some("humaneva"));
    assert_eq!(g.config_json(), json);
    // and from a file on disk
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "generator.safetensors", &bytes(&json, &t));
    assert_eq!(Generator::load(&p).unwrap().pred_len(), 12);
    assert!(matches!(
        Generator::load(dir.path().join("nope.safetensors")),
        Err(Error::NotFound { .. })
    ));
}

#[test]
fn config_errors_name_the_field() {
    let cfg = config();
    let (_, t) = generator(1);
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
        with(&cfg, |v| v["model"]["coefs"] = 13.into()),
        "model.coefs",
    );
    for field in [
        "num_joints",
        "coords",
        "obs_len",
        "pred_len",
        "hidden",
        "layers",
        "z_dim",
        "coefs",
    ] {
        invalid(
            with(&cfg, |v| v["model"][field] = 0.into()),
            &format!("model.{field}"),
        );
    }
    invalid(
        with(&cfg, |v| v["model"]["z_dim"] = u64::MAX.into()),
        "model.z_dim",
    );
    // a missing or mistyped field: the parser's message names it
    let e = load_err(
        &with(&cfg, |v| {
            drop(v["model"].as_object_mut().unwrap().remove("coefs"))
        }),
        &t,
    );
    assert!(
        matches!(e, Error::BadMetadata { .. }) && e.to_string().contains("coefs"),
        "{e}"
    );
    let e = load_err(&with(&cfg, |v| v["model"]["hidden"] = "wide".into()), &t);
    assert!(
        matches!(e, Error::BadMetadata { .. }) && e.to_string().contains("model.hidden"),
        "{e}"
    );
    let e = Generator::from_bytes(&serialize(&t, None), "g").unwrap_err();
    assert!(matches!(e, Error::MissingMetadata { .. }), "{e:?}");
}

#[test]
fn tensor_errors_name_the_tensor() {
    let json = config().to_json();
    let (_, good) = generator(1);
    let mut t = good.clone();
    t.remove("layers.1.bias");
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::MissingTensor { name, expected, .. } if name == "layers.1.bias" && expected == &vec![24]),
        "{e:?}"
    );
    let mut t = good.clone();
    t.insert(
        "layers.3.weight".into(),
        RawTensor::f32(vec![24, 24], &[0.0; 576]),
    );
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::UnexpectedTensor { name, .. } if name == "layers.3.weight"),
        "{e:?}"
    );
    // the first layer reads (O + C)·K + z_dim = 61 values, not the 54 without z
    let mut t = good.clone();
    t.insert(
        "layers.0.weight".into(),
        RawTensor::f32(vec![24, 54], &[0.0; 24 * 54]),
    );
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::TensorShape { name, expected, received, .. }
                     if name == "layers.0.weight" && expected == &vec![24, 61] && received == &vec![24, 54]),
        "{e:?}"
    );
    let mut t = good.clone();
    let mut w = t["head.weight"].values();
    w[3] = f32::INFINITY;
    t.insert("head.weight".into(), RawTensor::f32(vec![24, 24], &w));
    let e = load_err(&json, &t);
    assert!(
        matches!(&e, Error::NonFiniteTensor { name, index: 3, .. } if name == "head.weight"),
        "{e:?}"
    );
}

#[test]
fn each_kind_of_file_is_refused_by_role_by_the_others() {
    let (_, t) = generator(1);
    let file = bytes(&config().to_json(), &t);
    let role_error = |e: Error, loader: &str, python: &str| {
        assert!(
            matches!(&e, Error::InvalidConfig { field, .. } if field == "role"),
            "{e:?}"
        );
        let msg = e.to_string();
        assert!(msg.contains(loader) && msg.contains(python), "{msg}");
    };
    // a generator's file: neither a denoiser nor a prior
    let e = Denoiser::from_bytes(&file, "generator.safetensors").unwrap_err();
    assert!(e.to_string().contains("MLP sample generator"), "{e}");
    role_error(e, "`Generator::load`", "`tcd.engine.Generator.load`");
    let e = Prior::from_bytes(&file, "generator.safetensors").unwrap_err();
    assert!(e.to_string().contains("\"generator\""), "{e}");
    role_error(e, "`Generator::load`", "`tcd.engine.Generator.load`");
    // a prior's or a denoiser's role given to the generator's loader
    let json = with(&config(), |v| v["role"] = "prior".into());
    role_error(
        load_err(&json, &t),
        "`Prior::load`",
        "`tcd.engine.Prior.load`",
    );
    let json = with(&config(), |v| v["role"] = "short".into());
    role_error(
        load_err(&json, &t),
        "`Denoiser::load`",
        "`tcd.engine.Denoiser.load`",
    );
    let (_, dt) = tiny_model(tcd_core::Role::Short, 4, 2, 1);
    let short = tiny_config(tcd_core::Role::Short, 4, 2).to_json();
    role_error(
        Generator::from_bytes(&serialize(&dt, Some(short)), "short.safetensors").unwrap_err(),
        "`Denoiser::load`",
        "`tcd.engine.Denoiser.load`",
    );
}

// ------------------------------------------------------------------------------- sample

/// `Generator.forward` in f64 from training/generator.py's formulas: obs (B, T, K) (its last O frames),
/// prior (B, P, K), z (S, B, Z) → (S, B, P, K); S from the length of z.
fn naive_sample(
    cfg: &GeneratorModelConfig,
    t: &BTreeMap<String, RawTensor>,
    obs: &[f32],
    frames: usize,
    prior: &[f32],
    z: &[f32],
    batch: usize,
) -> Vec<f64> {
    let (k, o, p, c, zd, hid) = (
        cfg.num_features,
        cfg.obs_len,
        cfg.pred_len,
        cfg.coefs,
        cfg.z_dim,
        cfg.hidden,
    );
    let g = |name: &str| get(t, name);
    let samples = z.len() / (batch * zd);
    let (d_o, d_p) = (naive_dct(o), naive_dct(p));
    let mut out = vec![0.0f64; samples * batch * p * k];
    for b in 0..batch {
        let seen = &obs[(b * frames + frames - o) * k..(b + 1) * frames * k];
        let last = &seen[(o - 1) * k..];
        let fc = &prior[b * p * k..(b + 1) * p * k];
        let mut cond = Vec::new();
        for f in 0..o {
            for kk in 0..k {
                cond.push(
                    (0..o)
                        .map(|tt| d_o[f * o + tt] * (seen[tt * k + kk] - last[kk]) as f64)
                        .sum::<f64>(),
                );
            }
        }
        for f in 0..c {
            for kk in 0..k {
                cond.push(
                    (0..p)
                        .map(|tt| d_p[f * p + tt] * (fc[tt * k + kk] - last[kk]) as f64)
                        .sum::<f64>(),
                );
            }
        }
        for s in 0..samples {
            let mut h = cond.clone();
            h.extend(z[(s * batch + b) * zd..][..zd].iter().map(|&v| v as f64));
            for i in 0..cfg.layers {
                h = matvec(
                    &g(&format!("layers.{i}.weight")),
                    &g(&format!("layers.{i}.bias")),
                    &h,
                )
                .into_iter()
                .map(gelu)
                .collect();
                assert_eq!(h.len(), hid);
            }
            let y = matvec(&g("head.weight"), &g("head.bias"), &h);
            for tt in 0..p {
                for kk in 0..k {
                    out[((s * batch + b) * p + tt) * k + kk] = fc[tt * k + kk] as f64
                        + (0..c).map(|f| d_p[f * p + tt] * y[f * k + kk]).sum::<f64>();
                }
            }
        }
    }
    out
}

fn motion(n: usize, seed: u64) -> Vec<f32> {
    values(n, seed, 0.5)
}

#[test]
fn sample_matches_the_f64_reference_on_every_kernel() {
    let cfg = config();
    let (g, t) = generator(7);
    let (b, s, frames, k, p) = (3, 5, 8, 6, 12);
    // the frames before the last obs_len are not read: NaN there is fine
    let mut obs = motion(b * frames * k, 3);
    for seq in obs.chunks_exact_mut(frames * k) {
        seq[..k].fill(f32::NAN);
    }
    let prior = motion(b * p * k, 4);
    let z = seeded_noise(9, Sequences::From(0), stage::GENERATOR, s, 1, b, 7);
    let want = naive_sample(&cfg.model, &t, &obs, frames, &prior, &z, b);
    // the MLP's residual (sample − prior) is large against the tolerance
    let residual = (0..want.len())
        .map(|i| (want[i] - prior[i % (b * p * k)] as f64).abs())
        .fold(0.0, f64::max);
    assert!(residual > 0.3, "residual {residual}");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for kernel in Kernel::supported() {
        let gk = g.clone().with_kernel(kernel).unwrap();
        assert_eq!(gk.kernel(), kernel);
        let got = gk
            .sample(
                &obs,
                &prior,
                b,
                frames,
                s,
                Noise::Injected(&z),
                &Control::default(),
            )
            .unwrap();
        assert_eq!(got.len(), s * b * p * k);
        let err = max_abs_diff(&got, &want);
        assert!(
            err <= 1e-5 * scale.max(1.0),
            "{kernel}: max abs diff {err}, scale {scale}"
        );
        // the seeded call reads exactly `seeded_noise` of stage GENERATOR
        let seeded = gk
            .sample(
                &obs,
                &prior,
                b,
                frames,
                s,
                Noise::seeded(9),
                &Control::default(),
            )
            .unwrap();
        assert_eq!(seeded, got, "{kernel}");
    }
}

#[test]
fn seeded_results_do_not_depend_on_threads_or_batch_neighbours() {
    let (g, _) = generator(4);
    let (b, s, frames, k, p) = (7, 9, 5, 6, 12);
    let obs = motion(b * frames * k, 5);
    let prior = motion(b * p * k, 6);
    let run = |threads: usize, obs: &[f32], prior: &[f32], b: usize, noise: Noise<'_>| {
        with_threads(Some(threads), || {
            g.sample(obs, prior, b, frames, s, noise, &Control::default())
        })
        .unwrap()
        .unwrap()
    };
    let one = run(1, &obs, &prior, b, Noise::seeded(3));
    for threads in [2, 3, 8] {
        assert_eq!(
            one,
            run(threads, &obs, &prior, b, Noise::seeded(3)),
            "{threads} threads"
        );
    }
    let row = |v: &[f32], batch: usize, s: usize, seq: usize| -> Vec<f32> {
        v[(s * batch + seq) * p * k..][..p * k].to_vec()
    };
    // sequence 4 alone, as stream 4 (From) or by its id (Ids): its samples as in the batch
    let seq = |v: &[f32], n: usize| v[4 * n..5 * n].to_vec();
    let (o4, p4) = (seq(&obs, frames * k), seq(&prior, p * k));
    let from = Noise::Seeded {
        seed: 3,
        sequences: Sequences::From(4),
    };
    let alone = run(2, &o4, &p4, 1, from);
    // in a batch of two in the other order, numbered by ids
    let mut o2 = o4.clone();
    o2.extend_from_slice(&obs[..frames * k]);
    let mut p2 = p4.clone();
    p2.extend_from_slice(&prior[..p * k]);
    let ids = Noise::Seeded {
        seed: 3,
        sequences: Sequences::Ids(&[4, 0]),
    };
    let pair = run(3, &o2, &p2, 2, ids);
    for sample in 0..s {
        assert_eq!(
            row(&alone, 1, sample, 0),
            row(&one, b, sample, 4),
            "{sample}"
        );
        assert_eq!(
            row(&pair, 2, sample, 0),
            row(&one, b, sample, 4),
            "{sample}"
        );
        assert_eq!(
            row(&pair, 2, sample, 1),
            row(&one, b, sample, 0),
            "{sample}"
        );
    }
    // another seed, another stream
    assert_ne!(one, run(1, &obs, &prior, b, Noise::seeded(4)));
}

#[test]
fn bad_arguments_are_named() {
    let (g, _) = generator(1);
    let c = Control::default();
    let (b, s, frames, k, p) = (2, 3, 5, 6, 12);
    let obs = motion(b * frames * k, 1);
    let prior = motion(b * p * k, 2);
    let z = vec![0.5f32; s * b * 7];
    let noise = Noise::Injected(&z);
    assert!(g.sample(&obs, &prior, b, frames, s, noise, &c).is_ok());
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior, 0, frames, s, noise, &c)),
        "batch"
    );
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior, b, frames, 0, noise, &c)),
        "num_samples"
    );
    assert_eq!(
        invalid_argument(g.sample(&obs[..b * 4 * k], &prior, b, 4, s, noise, &c)),
        "obs"
    );
    assert_eq!(
        invalid_argument(g.sample(&obs[1..], &prior, b, frames, s, noise, &c)),
        "obs"
    );
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior[..p * k], b, frames, s, noise, &c)),
        "prior"
    );
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior, b, frames, s, Noise::Injected(&z[1..]), &c)),
        "noise"
    );
    assert_eq!(
        invalid_argument(g.sample(
            &obs,
            &prior,
            b,
            frames,
            usize::MAX / 8,
            Noise::seeded(0),
            &c
        )),
        "num_samples"
    );
    let ids = Noise::Seeded {
        seed: 0,
        sequences: Sequences::Ids(&[1, 2, 3]),
    };
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior, b, frames, s, ids, &c)),
        "sequences"
    );
    // non-finite values, named by their flat index
    let mut bad = obs.clone();
    bad[frames * k + 7] = f32::NAN;
    let e = g.sample(&bad, &prior, b, frames, s, noise, &c).unwrap_err();
    assert!(
        e.to_string()
            .contains(&format!("NaN at flat index {}", frames * k + 7)),
        "{e}"
    );
    let mut bad = prior.clone();
    bad[13] = f32::INFINITY;
    assert_eq!(
        invalid_argument(g.sample(&obs, &bad, b, frames, s, noise, &c)),
        "prior"
    );
    let mut bad = z.clone();
    bad[0] = f32::NAN;
    assert_eq!(
        invalid_argument(g.sample(&obs, &prior, b, frames, s, Noise::Injected(&bad), &c)),
        "noise"
    );
    let cancelled = Control::default();
    cancelled.cancel();
    assert!(matches!(
        g.sample(&obs, &prior, b, frames, s, noise, &cancelled),
        Err(Error::Cancelled)
    ));
}
