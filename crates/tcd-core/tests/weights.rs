//! Loader: one test per way a weight file can be wrong.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use safetensors::Dtype;
use tcd_core::FileConfig;
use tcd_core::{Denoiser, Error, Network, Role};

fn good() -> (
    tcd_core::TcdConfig,
    std::collections::BTreeMap<String, RawTensor>,
) {
    let cfg = tiny_config(Role::Short, 8, 2);
    let t = random_tensors(&cfg, 1);
    (cfg, t)
}

fn load_bytes(bytes: &[u8]) -> Result<Denoiser, Error> {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "w.safetensors", bytes);
    Denoiser::load(&p)
}

#[test]
fn good_file_loads_with_its_config() {
    let (cfg, t) = good();
    let json = cfg.to_json();
    let d = load_bytes(&serialize(&t, Some(json.clone()))).unwrap();
    assert_eq!(d.config(), &cfg);
    assert_eq!(d.config_json(), json);
    assert_eq!(d.num_features(), 6);
    assert_eq!(d.seq_len(), 10);
    assert_eq!(d.obs_len(), 8);
    assert_eq!(d.pred_len(), 2);
    assert_eq!(d.num_train_timesteps(), 10);
    assert_eq!(d.role(), Role::Short);
    assert!(d.path().ends_with("w.safetensors"));
    assert_eq!(d.schedule().betas(), cfg.diffusion.betas.as_slice());
    assert!(d.step_embedding(9).is_some() && d.step_embedding(10).is_none());
    let shapes = Denoiser::tensor_shapes(cfg.clone()).unwrap();
    assert_eq!(shapes.len(), t.len());
    for (name, shape) in shapes {
        assert_eq!(t[&name].shape, shape, "{name}");
    }
}

#[test]
fn unknown_config_keys_are_ignored_and_kept() {
    let (cfg, t) = good();
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["training"] = serde_json::json!({"epochs": 50});
    v["model"]["dropout"] = serde_json::json!(0.1);
    v["data"] = serde_json::json!({"dataset": "h36m", "fps": 25.0, "units": "m", "root_relative": true,
                                    "joint_names": ["a", "b"], "split": "S5"});
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().data.dataset.as_deref(), Some("h36m"));
    assert_eq!(d.config().data.extra["split"], serde_json::json!("S5"));
    assert!(d.config_json().contains("epochs"));
}

#[test]
fn missing_file_is_not_found() {
    let dir = tempfile::tempdir().unwrap();
    let e = Denoiser::load(dir.path().join("nope.safetensors")).unwrap_err();
    assert!(matches!(e, Error::NotFound { .. }), "{e:?}");
    assert!(e.to_string().contains("nope.safetensors"));
    assert!(!e.is_weights_error());
}

#[test]
fn directory_is_not_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let e = Denoiser::load(dir.path()).unwrap_err();
    assert!(matches!(e, Error::NotAFile { .. }), "{e:?}");
    assert!(
        e.is_weights_error() && e.to_string().contains("is a directory"),
        "{e}"
    );
}

#[test]
fn non_finite_weight_names_the_tensor() {
    let (cfg, t) = good();
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut t = t.clone();
        let name = t.keys().nth(3).unwrap().clone();
        let mut v = t[&name].values();
        v[1] = bad;
        t.insert(name.clone(), RawTensor::f32(t[&name].shape.clone(), &v));
        let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
        match &e {
            Error::NonFiniteTensor { name: n, index, .. } => {
                assert_eq!((n.as_str(), *index), (name.as_str(), 1))
            }
            other => panic!("{other:?}"),
        }
        assert!(
            e.is_weights_error() && e.to_string().contains(&format!("`{name}`")),
            "{e}"
        );
    }
}

/// Fuzzing the loader: random byte flips anywhere, truncations and edits of the JSON header of a valid
/// file. Every mutant either loads (then every tensor is finite and has its configured shape) or is a
/// weights error; none panics. `TCD_FUZZ_CASES` sets the count (CI: the default 3000, about a second;
/// the longer local run is in the issue note).
#[test]
fn fuzzed_weight_files_load_or_fail_cleanly() {
    use rand::{Rng, SeedableRng};
    let (cfg, t) = good();
    let valid = serialize(&t, Some(cfg.to_json()));
    let header_len = u64::from_le_bytes(valid[..8].try_into().unwrap()) as usize;
    let cases: usize = std::env::var("TCD_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3000);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    let (mut loaded, mut refused) = (0usize, 0usize);
    for case in 0..cases {
        let mut b = valid.clone();
        match case % 4 {
            0 => {
                // flip 1..8 random bits anywhere
                for _ in 0..rng.random_range(1..=8) {
                    let i = rng.random_range(0..b.len());
                    b[i] ^= 1 << rng.random_range(0..8);
                }
            }
            1 => b.truncate(rng.random_range(0..b.len())),
            2 => {
                // overwrite a byte of the JSON header (offsets, shapes, dtypes, the config) with printable ASCII
                let i = 8 + rng.random_range(0..header_len);
                b[i] = rng.random_range(32u8..127);
            }
            _ => {
                // the 8-byte header length itself
                let i = rng.random_range(0..8);
                b[i] = rng.random();
            }
        }
        let got = std::panic::catch_unwind(|| Denoiser::from_bytes(&b, "fuzz.safetensors"));
        match got {
            Err(_) => panic!("case {case}: the loader panicked"),
            // a mutant that loads kept every tensor whole (the loader checks each where it is taken)
            Ok(Ok(_)) => loaded += 1,
            Ok(Err(e)) => {
                refused += 1;
                assert!(e.is_weights_error(), "case {case}: {e:?}");
            }
        }
    }
    assert_eq!(loaded + refused, cases);
    assert!(
        refused > cases / 2,
        "most mutants must be refused ({refused} of {cases})"
    );
}

#[test]
fn truncated_file_is_corrupt() {
    let (cfg, t) = good();
    let bytes = serialize(&t, Some(cfg.to_json()));
    for cut in [0, 5, 100, bytes.len() - 1] {
        let e = load_bytes(&bytes[..cut]).unwrap_err();
        assert!(matches!(e, Error::Corrupt { .. }), "cut {cut}: {e:?}");
        assert!(e.to_string().contains("w.safetensors"), "{e}");
        assert!(e.is_weights_error());
    }
    let e = load_bytes(b"definitely not safetensors").unwrap_err();
    assert!(matches!(e, Error::Corrupt { .. }), "{e:?}");
}

#[test]
fn missing_metadata() {
    let (_, t) = good();
    let e = load_bytes(&serialize(&t, None)).unwrap_err();
    assert!(matches!(e, Error::MissingMetadata { .. }), "{e:?}");
    assert!(e.to_string().contains("tcd_config"));
}

#[test]
fn bad_json() {
    let (cfg, t) = good();
    let e = load_bytes(&serialize(&t, Some("{not json".into()))).unwrap_err();
    assert!(matches!(e, Error::BadMetadata { .. }), "{e:?}");
    assert!(e.to_string().contains("w.safetensors"));
    // valid JSON, wrong type / missing field
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["model"]["channels"] = serde_json::json!("sixteen");
    let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
    assert!(matches!(e, Error::BadMetadata { .. }), "{e:?}");
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v.as_object_mut().unwrap().remove("diffusion");
    let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
    assert!(e.to_string().contains("diffusion"), "{e}");
}

#[test]
fn missing_tensor() {
    let (cfg, mut t) = good();
    t.remove("diffmodel.residual_layers.1.time_layer.layers.0.norm2.bias");
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    match &e {
        Error::MissingTensor { name, expected, .. } => {
            assert_eq!(
                name,
                "diffmodel.residual_layers.1.time_layer.layers.0.norm2.bias"
            );
            assert_eq!(expected, &vec![16]);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn extra_tensor() {
    let (cfg, mut t) = good();
    t.insert(
        "diffmodel.diffusion_embedding.embedding".into(),
        RawTensor::f32(vec![2], &[0.0, 1.0]),
    );
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    assert!(
        matches!(&e, Error::UnexpectedTensor { name, .. } if name == "diffmodel.diffusion_embedding.embedding"),
        "{e:?}"
    );
}

#[test]
fn wrong_shape() {
    let (cfg, mut t) = good();
    t.insert(
        "diffmodel.input_projection.weight".into(),
        RawTensor::f32(vec![16, 2], &[0.0; 32]),
    );
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    match &e {
        Error::TensorShape {
            name,
            expected,
            received,
            ..
        } => {
            assert_eq!(name, "diffmodel.input_projection.weight");
            assert_eq!(expected, &vec![16, 2, 1]);
            assert_eq!(received, &vec![16, 2]);
        }
        other => panic!("{other:?}"),
    }
    assert!(e.to_string().contains("[16, 2, 1]"), "{e}");
}

#[test]
fn wrong_dtype() {
    let (cfg, mut t) = good();
    let w = t["embed_layer.weight"].clone();
    let f64_bytes: Vec<u8> = w
        .values()
        .iter()
        .flat_map(|v| (*v as f64).to_le_bytes())
        .collect();
    t.insert(
        "embed_layer.weight".into(),
        RawTensor {
            dtype: Dtype::F64,
            shape: w.shape.clone(),
            bytes: f64_bytes,
        },
    );
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    assert!(
        matches!(&e, Error::TensorDtype { name, received, .. } if name == "embed_layer.weight" && received == "F64"),
        "{e:?}"
    );
}

#[test]
fn betas_disagreeing_with_schedule() {
    let (mut cfg, t) = good();
    cfg.diffusion.betas[3] += 1e-6;
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    assert!(matches!(&e, Error::BetasMismatch { index: 3, .. }), "{e:?}");
    // a custom schedule name skips the recomputation but still needs betas in (0, 1)
    cfg.diffusion.beta_schedule = "custom".into();
    assert!(load_bytes(&serialize(&t, Some(cfg.to_json()))).is_ok());
    cfg.diffusion.betas[0] = 1.0;
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidConfig { field, .. } if field == "diffusion.betas"),
        "{e:?}"
    );
}

#[test]
fn quad_and_linear_schedules_are_checked() {
    let (mut cfg, t) = good();
    cfg.diffusion.beta_schedule = "quad".into();
    cfg.diffusion.betas = tcd_core::BetaSchedule::Quad.betas(10, 1e-4, 0.5, 0.5);
    assert!(load_bytes(&serialize(&t, Some(cfg.to_json()))).is_ok());
    cfg.diffusion.beta_schedule = "linear".into();
    let e = load_bytes(&serialize(&t, Some(cfg.to_json()))).unwrap_err();
    assert!(matches!(&e, Error::BetasMismatch { .. }), "{e:?}");
}

#[test]
fn inconsistent_configs() {
    let (cfg, t) = good();
    type Edit = Box<dyn Fn(&mut tcd_core::TcdConfig)>;
    let cases: Vec<(&str, Edit)> = vec![
        ("model.side_dim", Box::new(|c| c.model.side_dim = 36)),
        ("model.num_features", Box::new(|c| c.model.num_features = 7)),
        ("model.channels", Box::new(|c| c.model.num_heads = 3)),
        (
            "diffusion.betas",
            Box::new(|c| {
                c.diffusion.betas.pop();
            }),
        ),
        ("window.seq_len", Box::new(|c| c.window.seq_len = 11)),
        ("format_version", Box::new(|c| c.format_version = 2)),
        (
            "model.layer_norm_eps",
            Box::new(|c| c.model.layer_norm_eps = 0.0),
        ),
        (
            "model.target_scale",
            Box::new(|c| c.model.target_scale = 0.0),
        ),
        (
            "model.target_scale",
            Box::new(|c| c.model.target_scale = -5.0),
        ),
    ];
    for (field, edit) in cases {
        let mut c = cfg.clone();
        edit(&mut c);
        let e = load_bytes(&serialize(&t, Some(c.to_json()))).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidConfig { field: f, .. } if f == field),
            "{field}: {e:?}"
        );
        assert!(e.to_string().contains(field), "{e}");
    }
}

#[test]
fn unsupported_prediction_and_variance_types_are_refused_by_name() {
    let (cfg, t) = good();
    for (field, value) in [
        ("prediction_type", "v_prediction"),
        ("variance_type", "learned"),
    ] {
        let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
        v["diffusion"][field] = serde_json::json!(value);
        let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
        assert!(matches!(e, Error::BadMetadata { .. }), "{e:?}");
        assert!(e.to_string().contains(value), "{e}");
    }
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["diffusion"]["variance_type"] = serde_json::json!("fixed_large");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(
        d.config().diffusion.variance_type,
        tcd_core::VarianceType::FixedLarge
    );
}

#[test]
fn cond_fill_defaults_to_zero_parses_linear_and_rejects_others() {
    let (cfg, t) = good();
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["model"].as_object_mut().unwrap().remove("cond_fill");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().model.cond_fill, tcd_core::CondFill::Zero);
    v["model"]["cond_fill"] = serde_json::json!("linear");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().model.cond_fill, tcd_core::CondFill::Linear);
    v["model"]["cond_fill"] = serde_json::json!("cubic");
    let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
    assert!(matches!(e, Error::BadMetadata { .. }), "{e:?}");
    assert!(e.to_string().contains("cubic"), "{e}");
}

#[test]
fn target_defaults_to_absolute_parses_linear_residual_and_rejects_others() {
    let (cfg, t) = good();
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["model"].as_object_mut().unwrap().remove("target");
    v["model"].as_object_mut().unwrap().remove("target_scale");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().model.target, tcd_core::Target::Absolute);
    assert_eq!(d.config().model.target_scale, 1.0);
    v["model"]["target"] = serde_json::json!("linear_residual");
    v["model"]["target_scale"] = serde_json::json!(5.0);
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().model.target, tcd_core::Target::LinearResidual);
    assert_eq!(d.config().model.target_scale, 5.0);
    v["model"]["target"] = serde_json::json!("residual");
    let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
    assert!(matches!(e, Error::BadMetadata { .. }), "{e:?}");
    assert!(e.to_string().contains("residual"), "{e}");
}

#[test]
fn fill_linear_interpolates_holds_the_ends_and_skips_observed() {
    let nan = f32::NAN;
    let mask = [0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    let obs = [nan, 1.0, nan, nan, 4.0, nan, nan];
    let mut out = obs;
    let mut touched = Vec::new();
    tcd_core::fill_linear(&mask, &obs, |l, v| {
        touched.push(l);
        out[l] = v;
    });
    assert_eq!(touched, vec![0, 2, 3, 5, 6]);
    assert_eq!(out, [1.0, 1.0, 2.0, 3.0, 4.0, 4.0, 4.0]);
    let mut none = [9.0f32; 3];
    tcd_core::fill_linear(&[0.0; 3], &[nan; 3], |l, v| none[l] = v);
    assert_eq!(none, [0.0; 3]);
}

#[test]
fn prior_fill_and_prior_residual_parse_together_and_not_alone() {
    use tcd_core::{CondFill, Target};
    let (cfg, t) = good();
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["model"]["cond_fill"] = serde_json::json!("prior");
    v["model"]["target"] = serde_json::json!("prior_residual");
    v["model"]["target_scale"] = serde_json::json!(10.0);
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().model.cond_fill, CondFill::Prior);
    assert_eq!(d.config().model.target, Target::PriorResidual);
    assert_eq!(
        d.config().model.target.residual_fill(),
        Some(CondFill::Prior)
    );
    // round trip: the names written back are the ones read
    let back: serde_json::Value = serde_json::from_str(&d.config().to_json()).unwrap();
    assert_eq!(back["model"]["cond_fill"], "prior");
    assert_eq!(back["model"]["target"], "prior_residual");
    // one without the other: refused, naming the field that is set and the one it needs
    for (fill, target, field, other) in [
        ("prior", "absolute", "model.cond_fill", "prior_residual"),
        (
            "prior",
            "spline_residual",
            "model.cond_fill",
            "prior_residual",
        ),
        (
            "zero",
            "prior_residual",
            "model.target",
            "cond_fill \"prior\"",
        ),
        (
            "spline",
            "prior_residual",
            "model.target",
            "cond_fill \"prior\"",
        ),
    ] {
        v["model"]["cond_fill"] = serde_json::json!(fill);
        v["model"]["target"] = serde_json::json!(target);
        let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidConfig { field: f, .. } if f == field),
            "{fill}/{target}: {e:?}"
        );
        assert!(e.is_weights_error());
        let msg = e.to_string();
        assert!(
            msg.contains(field) && msg.contains(other) && msg.contains("go together"),
            "{msg}"
        );
    }
    // a Target without the Prior fill in code too (config built directly, then validated)
    let mut c = cfg.clone();
    c.model.target = Target::PriorResidual;
    let e = c.validate(std::path::Path::new("x")).unwrap_err();
    assert!(e.to_string().contains("`model.target`"), "{e}");
}

#[test]
fn prediction_type_sample_parses() {
    use tcd_core::PredictionType;
    let (cfg, t) = good();
    let mut v: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    v["diffusion"]["prediction_type"] = serde_json::json!("sample");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(d.config().diffusion.prediction_type, PredictionType::Sample);
    let back: serde_json::Value = serde_json::from_str(&d.config().to_json()).unwrap();
    assert_eq!(back["diffusion"]["prediction_type"], "sample");
    v["diffusion"]["prediction_type"] = serde_json::json!("epsilon");
    let d = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap();
    assert_eq!(
        d.config().diffusion.prediction_type,
        PredictionType::Epsilon
    );
    // a required field: absent is an error, as before
    v["diffusion"]
        .as_object_mut()
        .unwrap()
        .remove("prediction_type");
    let e = load_bytes(&serialize(&t, Some(v.to_string()))).unwrap_err();
    assert!(e.to_string().contains("prediction_type"), "{e}");
}
