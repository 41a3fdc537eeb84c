//! Tiny fixtures for the integration tests: configs, random weights written as safetensors, and a
//! naive f64 reference forward written from the PyTorch formulas in (B, C, K, L) layout.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use safetensors::tensor::TensorView;
use safetensors::Dtype;
use tcd_core::*;

/// K = 6 (2 joints x 3), C = 16, 2 layers, 2 heads, FFN 16, D = 32, time emb 32, E = 4, T = 10.
pub fn tiny_config(role: Role, obs_len: usize, pred_len: usize) -> TcdConfig {
    let t = 10;
    TcdConfig {
        format_version: 1,
        role,
        model: ModelConfig {
            num_joints: 2,
            coords: 3,
            num_features: 6,
            channels: 16,
            num_layers: 2,
            num_heads: 2,
            ffn_dim: 16,
            diffusion_embedding_dim: 32,
            time_embedding_dim: 32,
            feature_embedding_dim: 4,
            side_dim: 37,
            layer_norm_eps: 1e-5,
            cond_fill: Default::default(),
            target: Default::default(),
            target_scale: 1.0,
        },
        window: WindowConfig {
            obs_len,
            pred_len,
            seq_len: obs_len + pred_len,
        },
        diffusion: DiffusionConfig {
            num_train_timesteps: t,
            beta_schedule: "cosine".into(),
            beta_start: 1e-4,
            beta_end: 0.5,
            max_beta: 0.5,
            betas: BetaSchedule::Cosine.betas(t, 1e-4, 0.5, 0.5),
            prediction_type: tcd_core::PredictionType::Epsilon,
            variance_type: tcd_core::VarianceType::FixedSmall,
        },
        data: DataConfig::default(),
    }
}

/// A tensor as it will be written.
#[derive(Clone, Debug)]
pub struct RawTensor {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub bytes: Vec<u8>,
}

impl RawTensor {
    pub fn f32(shape: Vec<usize>, data: &[f32]) -> Self {
        RawTensor {
            dtype: Dtype::F32,
            shape,
            bytes: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    pub fn values(&self) -> Vec<f32> {
        self.bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }
}

/// Random weights for every expected tensor: N(0, 1/fan_in)-ish uniforms, LayerNorm weights near 1.
pub fn random_tensors(cfg: &TcdConfig, seed: u64) -> BTreeMap<String, RawTensor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = BTreeMap::new();
    for (name, shape) in Denoiser::tensor_shapes(cfg.clone()).unwrap() {
        let n: usize = shape.iter().product();
        let fan_in = if shape.len() >= 2 {
            shape[1..].iter().product::<usize>()
        } else {
            1
        };
        let scale = (3.0 / fan_in as f32).sqrt();
        let data: Vec<f32> = if name.contains("norm") && name.ends_with("weight") {
            (0..n)
                .map(|_| 1.0 + rng.random_range(-0.2f32..0.2))
                .collect()
        } else if name.ends_with("bias") || name.ends_with("in_proj_bias") {
            (0..n).map(|_| rng.random_range(-0.1f32..0.1)).collect()
        } else if name == "embed_layer.weight" {
            (0..n).map(|_| rng.random_range(-1.5f32..1.5)).collect()
        } else {
            (0..n).map(|_| rng.random_range(-scale..scale)).collect()
        };
        out.insert(name, RawTensor::f32(shape, &data));
    }
    out
}

/// Serialises tensors with the given `tcd_config` JSON (None: no metadata at all).
pub fn serialize(tensors: &BTreeMap<String, RawTensor>, config_json: Option<String>) -> Vec<u8> {
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(k, t)| {
            (
                k.clone(),
                TensorView::new(t.dtype, t.shape.clone(), &t.bytes).unwrap(),
            )
        })
        .collect();
    let meta = config_json.map(|j| HashMap::from([(CONFIG_KEY.to_string(), j)]));
    safetensors::serialize(views, meta).unwrap()
}

/// A weight file's bytes: tensors `t` with `cfg_json` as its `tcd_config`.
pub fn bytes(cfg_json: &str, t: &BTreeMap<String, RawTensor>) -> Vec<u8> {
    serialize(t, Some(cfg_json.to_string()))
}

/// The JSON of `cfg` (a prior's or a generator's config, as its `to_json` writes it) after `edit`:
/// a file's config with a field changed, added or removed.
pub fn with(cfg: &impl serde::Serialize, edit: impl FnOnce(&mut serde_json::Value)) -> String {
    let mut v = serde_json::to_value(cfg).unwrap();
    edit(&mut v);
    v.to_string()
}

/// Seeded uniform weights for the `expected` tensors (name, shape) of a prior or a generator: a
/// matrix ±sqrt(`gain` / fan_in), anything else ±0.3, a layer norm's `norm_weight` around 1.
pub fn uniform_tensors(
    expected: Vec<(String, Vec<usize>)>,
    gain: f32,
    seed: u64,
) -> BTreeMap<String, RawTensor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    expected
        .into_iter()
        .map(|(name, shape)| {
            let n: usize = shape.iter().product();
            let a = if shape.len() == 2 {
                (gain / shape[1] as f32).sqrt()
            } else {
                0.3
            };
            let centre = if name.ends_with("norm_weight") {
                1.0
            } else {
                0.0
            };
            let data: Vec<f32> = (0..n).map(|_| centre + rng.random_range(-a..a)).collect();
            (name, RawTensor::f32(shape, &data))
        })
        .collect()
}

/// A prior's random weights: [`uniform_tensors`] of gain 3 (N(0, 1/fan_in) scale), norm weights
/// around 1, so the network's contribution is large.
pub fn prior_tensors(cfg: &PriorConfig, seed: u64) -> BTreeMap<String, RawTensor> {
    uniform_tensors(Prior::tensor_shapes(cfg.clone()).unwrap(), 3.0, seed)
}

/// The config field an [`Error::InvalidConfig`] names; any other error fails the test.
pub fn invalid_field(e: Error) -> String {
    match e {
        Error::InvalidConfig { field, .. } => field,
        e => panic!("{e:?}"),
    }
}

/// The argument an [`Error::InvalidInput`] names; any other result fails the test.
pub fn invalid_argument(r: std::result::Result<Vec<f32>, Error>) -> String {
    match r {
        Err(Error::InvalidInput { argument, .. }) => argument,
        other => panic!("{other:?}"),
    }
}

pub fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// A tiny model straight from bytes.
pub fn tiny_model(
    role: Role,
    obs_len: usize,
    pred_len: usize,
    seed: u64,
) -> (Denoiser, BTreeMap<String, RawTensor>) {
    let cfg = tiny_config(role, obs_len, pred_len);
    let tensors = random_tensors(&cfg, seed);
    let bytes = serialize(&tensors, Some(cfg.to_json()));
    (
        Denoiser::from_bytes(&bytes, format!("tiny-{}.safetensors", role.as_str())).unwrap(),
        tensors,
    )
}

/// Deterministic pseudo-random f32 values in [-a, a].
pub fn values(n: usize, seed: u64, a: f32) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(-a..a)).collect()
}

/// A random binary mask.
pub fn binary_mask(n: usize, seed: u64, p_one: f64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| if rng.random_bool(p_one) { 1.0 } else { 0.0 })
        .collect()
}

pub fn max_abs_diff(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - y).abs())
        .fold(0.0, f64::max)
}

// ------------------------------------------------------------------ naive f64 reference

/// The diffusion-step table as `training/model.py` builds it, (num_steps × dim): row t =
/// `[sin(t·f_j)]_j ++ [cos(t·f_j)]_j`, f_j = 10^(4·j / (dim/2 − 1)), with PyTorch's f32 products.
fn step_embedding_table(num_steps: usize, dim: usize) -> Vec<f32> {
    let half = dim / 2;
    let denom = half.saturating_sub(1).max(1) as f32;
    let freqs: Vec<f32> = (0..half)
        .map(|j| 10f64.powf((j as f32 / denom * 4.0f32) as f64) as f32)
        .collect();
    let mut table = vec![0.0f32; num_steps * dim];
    for (t, row) in table.chunks_exact_mut(dim.max(1)).enumerate() {
        for (j, &f) in freqs.iter().enumerate() {
            let arg = t as f32 * f;
            row[j] = (arg as f64).sin() as f32;
            row[half + j] = (arg as f64).cos() as f32;
        }
    }
    table
}

/// The frame-position embedding as `training/model.py` builds it, (length × dim): `pe[pos, 2i] =
/// sin(pos·div_i)`, `pe[pos, 2i+1] = cos(pos·div_i)`, `div_i = exp(2i · (−ln(10000)/dim))` in f32.
fn frame_embedding(length: usize, dim: usize) -> Vec<f32> {
    let coef = (-(10000f64.ln() / dim as f64)) as f32;
    let div: Vec<f32> = (0..dim / 2)
        .map(|i| (((2 * i) as f32 * coef) as f64).exp() as f32)
        .collect();
    let mut pe = vec![0.0f32; length * dim];
    for (pos, row) in pe.chunks_exact_mut(dim.max(1)).enumerate() {
        for (i, &d) in div.iter().enumerate() {
            let arg = pos as f32 * d;
            row[2 * i] = (arg as f64).sin() as f32;
            row[2 * i + 1] = (arg as f64).cos() as f32;
        }
    }
    pe
}

/// Tensor `name` of `t` in f64.
pub fn get(t: &BTreeMap<String, RawTensor>, name: &str) -> Vec<f64> {
    t[name].values().iter().map(|&v| v as f64).collect()
}

/// y[o] = Σ_i W[o][i] x[i] + b[o], W row-major (out, in).
pub fn matvec(w: &[f64], b: &[f64], x: &[f64]) -> Vec<f64> {
    let out = b.len();
    let inp = x.len();
    (0..out)
        .map(|o| b[o] + (0..inp).map(|i| w[o * inp + i] * x[i]).sum::<f64>())
        .collect()
}

fn silu(x: f64) -> f64 {
    x / (1.0 + (-x).exp())
}
fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}
/// The exact (erf) GELU.
pub fn gelu(x: f64) -> f64 {
    0.5 * x * (1.0 + libm::erf(x / std::f64::consts::SQRT_2))
}

/// The orthonormal DCT-II matrix (n × n, row f the f-th cosine) in f64, from its formula: the
/// prior's and the generator's references.
pub fn naive_dct(n: usize) -> Vec<f64> {
    (0..n * n)
        .map(|i| {
            let (f, j) = (i / n, i % n);
            let v = (2.0 / n as f64).sqrt()
                * (std::f64::consts::PI * (2 * j + 1) as f64 * f as f64 / (2.0 * n as f64)).cos();
            if f == 0 {
                v / 2f64.sqrt()
            } else {
                v
            }
        })
        .collect()
}

fn layer_norm(x: &mut [f64], w: &[f64], b: &[f64], eps: f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    for (i, v) in x.iter_mut().enumerate() {
        *v = (*v - mean) / (var + eps).sqrt() * w[i] + b[i];
    }
}

/// nn.TransformerEncoderLayer (post-norm, eval) on one sequence.
fn encoder(t: &BTreeMap<String, RawTensor>, prefix: &str, cfg: &ModelConfig, seq: &mut [Vec<f64>]) {
    let c = cfg.channels;
    let heads = cfg.num_heads;
    let hd = c / heads;
    let w_in = get(t, &format!("{prefix}.self_attn.in_proj_weight"));
    let b_in = get(t, &format!("{prefix}.self_attn.in_proj_bias"));
    let w_out = get(t, &format!("{prefix}.self_attn.out_proj.weight"));
    let b_out = get(t, &format!("{prefix}.self_attn.out_proj.bias"));
    let qkv: Vec<Vec<f64>> = seq.iter().map(|x| matvec(&w_in, &b_in, x)).collect();
    let len = seq.len();
    let mut att = vec![vec![0.0; c]; len];
    for h in 0..heads {
        for i in 0..len {
            let s: Vec<f64> = (0..len)
                .map(|j| {
                    (0..hd)
                        .map(|d| qkv[i][h * hd + d] * qkv[j][c + h * hd + d])
                        .sum::<f64>()
                        / (hd as f64).sqrt()
                })
                .collect();
            let m = s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let e: Vec<f64> = s.iter().map(|v| (v - m).exp()).collect();
            let z: f64 = e.iter().sum();
            for j in 0..len {
                for d in 0..hd {
                    att[i][h * hd + d] += e[j] / z * qkv[j][2 * c + h * hd + d];
                }
            }
        }
    }
    let eps = cfg.layer_norm_eps;
    let (n1w, n1b) = (
        get(t, &format!("{prefix}.norm1.weight")),
        get(t, &format!("{prefix}.norm1.bias")),
    );
    let (n2w, n2b) = (
        get(t, &format!("{prefix}.norm2.weight")),
        get(t, &format!("{prefix}.norm2.bias")),
    );
    let (l1w, l1b) = (
        get(t, &format!("{prefix}.linear1.weight")),
        get(t, &format!("{prefix}.linear1.bias")),
    );
    let (l2w, l2b) = (
        get(t, &format!("{prefix}.linear2.weight")),
        get(t, &format!("{prefix}.linear2.bias")),
    );
    for (x, a) in seq.iter_mut().zip(&att) {
        let sa = matvec(&w_out, &b_out, a);
        for (v, s) in x.iter_mut().zip(&sa) {
            *v += s;
        }
        layer_norm(x, &n1w, &n1b, eps);
        let hidden: Vec<f64> = matvec(&l1w, &l1b, x).into_iter().map(gelu).collect();
        let ff = matvec(&l2w, &l2b, &hidden);
        for (v, f) in x.iter_mut().zip(&ff) {
            *v += f;
        }
        layer_norm(x, &n2w, &n2b, eps);
    }
}

/// The whole denoiser in f64, written from the PyTorch formulas; `shape` = (B, L), returns (B, K, L).
pub fn naive_forward(
    cfg: &TcdConfig,
    t: &BTreeMap<String, RawTensor>,
    noisy: &[f32],
    observed: &[f32],
    mask: &[f32],
    shape: (usize, usize),
    step: usize,
) -> Vec<f64> {
    let (batch, length) = shape;
    let m = &cfg.model;
    let (k, l, c, d, te, e) = (
        m.num_features,
        length,
        m.channels,
        m.diffusion_embedding_dim,
        m.time_embedding_dim,
        m.feature_embedding_dim,
    );
    let n = k * l;
    let s_dim = m.side_dim;
    let pe: Vec<f64> = frame_embedding(l, te).iter().map(|&v| v as f64).collect();
    let table: Vec<f64> = step_embedding_table(cfg.diffusion.num_train_timesteps, d)
        .iter()
        .map(|&v| v as f64)
        .collect();
    let emb = get(t, "embed_layer.weight");
    // step embedding
    let e1 = matvec(
        &get(t, "diffmodel.diffusion_embedding.projection1.weight"),
        &get(t, "diffmodel.diffusion_embedding.projection1.bias"),
        &table[step * d..(step + 1) * d],
    );
    let e1: Vec<f64> = e1.into_iter().map(silu).collect();
    let e2 = matvec(
        &get(t, "diffmodel.diffusion_embedding.projection2.weight"),
        &get(t, "diffmodel.diffusion_embedding.projection2.bias"),
        &e1,
    );
    let demb: Vec<f64> = e2.into_iter().map(silu).collect();

    let mut out = vec![0.0; batch * n];
    let w_inp = get(t, "diffmodel.input_projection.weight");
    let b_inp = get(t, "diffmodel.input_projection.bias");
    for b in 0..batch {
        let idx = |kk: usize, ll: usize| b * n + kk * l + ll;
        // h: (C, K, L) as h[c][kk*l + ll]
        let mut h = vec![vec![0.0f64; n]; c];
        let mut side = vec![vec![0.0f64; n]; s_dim];
        for kk in 0..k {
            for ll in 0..l {
                let i = idx(kk, ll);
                let mv = mask[i] as f64;
                let in0 = mv * observed[i] as f64;
                let in1 = (1.0 - mv) * noisy[i] as f64;
                for ch in 0..c {
                    h[ch][kk * l + ll] =
                        (w_inp[ch * 2] * in0 + w_inp[ch * 2 + 1] * in1 + b_inp[ch]).max(0.0);
                }
                for s in 0..te {
                    side[s][kk * l + ll] = pe[ll * te + s];
                }
                for s in 0..e {
                    side[te + s][kk * l + ll] = emb[kk * e + s];
                }
                side[te + e][kk * l + ll] = mv;
            }
        }
        let mut skip = vec![vec![0.0f64; n]; c];
        for i in 0..m.num_layers {
            let p = format!("diffmodel.residual_layers.{i}");
            let dp = matvec(
                &get(t, &format!("{p}.diffusion_projection.weight")),
                &get(t, &format!("{p}.diffusion_projection.bias")),
                &demb,
            );
            let mut y: Vec<Vec<f64>> = (0..c)
                .map(|ch| h[ch].iter().map(|v| v + dp[ch]).collect())
                .collect();
            if l > 1 {
                for kk in 0..k {
                    let mut seq: Vec<Vec<f64>> = (0..l)
                        .map(|ll| (0..c).map(|ch| y[ch][kk * l + ll]).collect())
                        .collect();
                    encoder(t, &format!("{p}.time_layer.layers.0"), m, &mut seq);
                    for ll in 0..l {
                        for ch in 0..c {
                            y[ch][kk * l + ll] = seq[ll][ch];
                        }
                    }
                }
            }
            if k > 1 {
                for ll in 0..l {
                    let mut seq: Vec<Vec<f64>> = (0..k)
                        .map(|kk| (0..c).map(|ch| y[ch][kk * l + ll]).collect())
                        .collect();
                    encoder(t, &format!("{p}.feature_layer.layers.0"), m, &mut seq);
                    for kk in 0..k {
                        for ch in 0..c {
                            y[ch][kk * l + ll] = seq[kk][ch];
                        }
                    }
                }
            }
            let wm = get(t, &format!("{p}.mid_projection.weight"));
            let bm = get(t, &format!("{p}.mid_projection.bias"));
            let wc = get(t, &format!("{p}.cond_projection.weight"));
            let bc = get(t, &format!("{p}.cond_projection.bias"));
            let wo = get(t, &format!("{p}.output_projection.weight"));
            let bo = get(t, &format!("{p}.output_projection.bias"));
            for tok in 0..n {
                let yv: Vec<f64> = (0..c).map(|ch| y[ch][tok]).collect();
                let sv: Vec<f64> = (0..s_dim).map(|s| side[s][tok]).collect();
                let mid = matvec(&wm, &bm, &yv);
                let cond = matvec(&wc, &bc, &sv);
                let z: Vec<f64> = mid.iter().zip(&cond).map(|(a, b)| a + b).collect();
                let g: Vec<f64> = (0..c).map(|ch| sigmoid(z[ch]) * z[c + ch].tanh()).collect();
                let o = matvec(&wo, &bo, &g);
                for ch in 0..c {
                    h[ch][tok] = (h[ch][tok] + o[ch]) / std::f64::consts::SQRT_2;
                    skip[ch][tok] += o[c + ch];
                }
            }
        }
        let w1 = get(t, "diffmodel.output_projection1.weight");
        let b1 = get(t, "diffmodel.output_projection1.bias");
        let w2 = get(t, "diffmodel.output_projection2.weight");
        let b2 = get(t, "diffmodel.output_projection2.bias");
        for tok in 0..n {
            let sv: Vec<f64> = (0..c)
                .map(|ch| skip[ch][tok] / (m.num_layers as f64).sqrt())
                .collect();
            let r: Vec<f64> = matvec(&w1, &b1, &sv)
                .into_iter()
                .map(|v| v.max(0.0))
                .collect();
            out[b * n + tok] = matvec(&w2, &b2, &r)[0];
        }
    }
    out
}

/// A tiny model of `cfg` (edited by the caller: its fill, target, prediction type) straight from bytes.
pub fn model_of(cfg: &TcdConfig, seed: u64) -> Denoiser {
    let tensors = random_tensors(cfg, seed);
    Denoiser::from_bytes(
        &serialize(&tensors, Some(cfg.to_json())),
        format!("tiny-{}.safetensors", cfg.role.as_str()),
    )
    .unwrap()
}

/// A small random prior forecaster: K = `num_features`, `obs_len` frames in, `chunk` out, 2 blocks,
/// weights of unit-gain scale (its forecast moves well away from the last pose).
pub fn tiny_prior(num_features: usize, obs_len: usize, chunk: usize, seed: u64) -> Prior {
    tiny_prior_anchored(
        num_features,
        obs_len,
        chunk,
        Anchor::Last,
        GapFill::None,
        seed,
    )
}

/// A repair fill (anchor "window") of `len` frames with random weights, like [`tiny_prior`].
pub fn tiny_repair_fill(num_features: usize, len: usize, seed: u64) -> Prior {
    tiny_prior_anchored(num_features, len, len, Anchor::Window, GapFill::None, seed)
}

/// [`tiny_repair_fill`] that fills whole-frame gaps with the forecaster (`gap_fill: "forecaster"`).
pub fn tiny_gap_repair_fill(num_features: usize, len: usize, seed: u64) -> Prior {
    tiny_prior_anchored(
        num_features,
        len,
        len,
        Anchor::Window,
        GapFill::Forecaster,
        seed,
    )
}

pub fn tiny_prior_anchored(
    num_features: usize,
    obs_len: usize,
    chunk: usize,
    anchor: Anchor,
    gap_fill: GapFill,
    seed: u64,
) -> Prior {
    let cfg = PriorConfig {
        format_version: 1,
        role: "prior".into(),
        model: PriorModelConfig {
            num_joints: num_features / 3,
            coords: 3,
            num_features,
            obs_len,
            chunk,
            blocks: 2,
            layer_norm_eps: 1e-5,
            anchor,
            gap_fill,
            inbetween_context: 0,
            inbetween_max_gap: 0,
            joint_inbetween_context: 0,
            joint_inbetween_max_gap: 0,
        },
        data: DataConfig::default(),
    };
    let tensors = prior_tensors(&cfg, seed);
    Prior::from_bytes(&bytes(&cfg.to_json(), &tensors), "prior.safetensors").unwrap()
}
