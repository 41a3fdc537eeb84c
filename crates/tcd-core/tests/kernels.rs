//! Every kernel this CPU supports against the portable reference (and the naive f64 forward),
//! on tiny, odd and full-size shapes.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use tcd_core::FileConfig;
use tcd_core::{Denoiser, Kernel, Network, Observation, Role, TcdConfig, Workspace};

/// A config with the given sizes (K = joints·3).
fn config(
    joints: usize,
    channels: usize,
    heads: usize,
    ffn: usize,
    layers: usize,
    obs: usize,
    pred: usize,
) -> TcdConfig {
    let mut cfg = tiny_config(Role::Long, obs, pred);
    let m = &mut cfg.model;
    m.num_joints = joints;
    m.num_features = joints * 3;
    m.channels = channels;
    m.num_heads = heads;
    m.ffn_dim = ffn;
    m.num_layers = layers;
    m.diffusion_embedding_dim = 128;
    m.time_embedding_dim = 128;
    m.feature_embedding_dim = 16;
    m.side_dim = 128 + 16 + 1;
    cfg
}

fn model(cfg: &TcdConfig, seed: u64) -> Denoiser {
    let bytes = serialize(&random_tensors(cfg, seed), Some(cfg.to_json()));
    Denoiser::from_bytes(&bytes, "kernels.safetensors").unwrap()
}

/// Max |fast − portable| over a batch of 2 sequences at a few steps, for every supported kernel;
/// asserts it is at most `tol`.
fn compare_all(cfg: &TcdConfig, seed: u64, tol: f64) {
    let base = model(cfg, seed);
    let portable = base.clone().with_kernel(Kernel::Portable).unwrap();
    assert_eq!(portable.kernel(), Kernel::Portable);
    let (b, k, l) = (2usize, cfg.model.num_features, cfg.window.seq_len);
    let n = b * k * l;
    let noisy = values(n, seed + 1, 1.5);
    let observed = values(n, seed + 2, 0.8);
    let mask = binary_mask(n, seed + 3, 0.5);
    let steps = [0usize, 5, 9];
    let want: Vec<Vec<f32>> = steps
        .iter()
        .map(|&s| {
            let mut o = vec![0.0f32; n];
            portable
                .forward(
                    &noisy,
                    &Observation::new(&observed, &mask, [b, k, l]).unwrap(),
                    s,
                    &mut o,
                )
                .unwrap();
            o
        })
        .collect();
    for kernel in Kernel::supported() {
        let fast = base.clone().with_kernel(kernel).unwrap();
        assert_eq!(fast.kernel(), kernel);
        let prepared = fast
            .prepare(&Observation::new(&observed, &mask, [b, k, l]).unwrap())
            .unwrap();
        let mut ws = Workspace::new(&fast, l);
        for (&s, w) in steps.iter().zip(&want) {
            let mut o = vec![0.0f32; n];
            fast.forward_with_workspace(&prepared, &mut ws, &noisy, s, &mut o)
                .unwrap();
            assert!(o.iter().all(|v| v.is_finite()));
            let err = o
                .iter()
                .zip(w)
                .map(|(a, b)| (a - b).abs() as f64)
                .fold(0.0, f64::max);
            let scale = w.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            eprintln!(
                "{kernel}: K={k} L={l} C={} heads={} F={} step {s}: max |diff| {err:e} (scale {scale})",
                cfg.model.channels, cfg.model.num_heads, cfg.model.ffn_dim
            );
            assert!(err <= tol, "{kernel}: max |diff| {err:e} > {tol:e}");
            if kernel == Kernel::Portable {
                assert_eq!(&o, w, "the portable kernel is deterministic");
            }
        }
    }
}

#[test]
fn tiny_config_all_kernels_match_portable() {
    // K = 6, C = 16, 2 heads (head dim 8), FFN 16, L = 10 and 13.
    compare_all(&tiny_config(Role::Short, 8, 2), 21, 1e-5);
    compare_all(&tiny_config(Role::Short, 11, 2), 22, 1e-5);
}

#[test]
fn odd_sizes_all_kernels_match_portable() {
    // C not a multiple of the vector width, head dims 8, 4, 5 (portable attention fallback),
    // odd FFN widths, L = 1, odd K and L.
    for (joints, c, heads, f, obs, pred) in [
        (5usize, 24usize, 3usize, 40usize, 9usize, 4usize), // K = 15, hd 8, C = 24
        (3, 20, 4, 24, 6, 1),                               // hd 5 (fallback)
        (4, 32, 8, 48, 16, 1),                              // hd 4, L = 17
        (2, 32, 2, 33, 7, 0),                               // hd 16, F = 33
        (3, 48, 6, 64, 1, 0),                               // L = 1 (no time transformer)
        (1, 16, 2, 16, 12, 3),                              // K = 3
    ] {
        let cfg = config(joints, c, heads, f, 2, obs, pred);
        compare_all(&cfg, 31 + c as u64, 1e-5);
    }
}

#[test]
fn reduced_config_c32_matches_portable() {
    // The reduced training config: C = 32, 4 heads (head dim 8), K = 66, L = 55.
    let cfg = config(22, 32, 4, 64, 2, 50, 5);
    compare_all(&cfg, 41, 1e-5);
}

#[test]
fn full_size_matches_portable() {
    // The paper's shapes: K = 66, C = 64, 8 heads, FFN 64, L = 75 and 55 (2 of the 12 layers).
    for (obs, pred) in [(55usize, 20usize), (50, 5)] {
        let cfg = config(22, 64, 8, 64, 2, obs, pred);
        compare_all(&cfg, 51 + obs as u64, 1e-5);
    }
}

#[test]
fn every_kernel_matches_the_naive_reference() {
    let (_, tensors) = tiny_model(Role::Short, 8, 2, 11);
    let cfg = tiny_config(Role::Short, 8, 2);
    let base = Denoiser::from_bytes(&serialize(&tensors, Some(cfg.to_json())), "t").unwrap();
    let (b, k, l) = (2usize, 6usize, 10usize);
    let n = b * k * l;
    let (noisy, observed, mask) = (values(n, 1, 1.5), values(n, 2, 0.8), binary_mask(n, 3, 0.5));
    for kernel in Kernel::supported() {
        let d = base.clone().with_kernel(kernel).unwrap();
        for step in [0usize, 9] {
            let mut out = vec![0.0f32; n];
            d.forward(
                &noisy,
                &Observation::new(&observed, &mask, [b, k, l]).unwrap(),
                step,
                &mut out,
            )
            .unwrap();
            let want = naive_forward(d.config(), &tensors, &noisy, &observed, &mask, (b, l), step);
            let scale = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = max_abs_diff(&out, &want);
            assert!(err < 1e-5 * scale.max(1.0), "{kernel} step {step}: {err}");
        }
    }
}

#[test]
fn forcing_portable_and_unsupported_kernels() {
    let (d, _) = tiny_model(Role::Short, 8, 2, 3);
    assert_ne!(d.kernel(), Kernel::Auto);
    let p = d.clone().with_kernel(Kernel::Portable).unwrap();
    assert_eq!(p.kernel(), Kernel::Portable);
    let auto = d.clone().with_kernel(Kernel::Auto).unwrap();
    assert_eq!(auto.kernel(), *Kernel::supported().last().unwrap());
    for k in [Kernel::Avx2, Kernel::Avx512] {
        let r = d.clone().with_kernel(k);
        assert_eq!(r.is_ok(), k.is_supported(), "{k}");
        if let Err(e) = r {
            assert!(e.to_string().contains("kernel"), "{e}");
        }
    }
    // A workspace made for one kernel is rebuilt for another.
    let n = 6 * 10;
    let (x, mask) = (values(n, 1, 1.0), binary_mask(n, 2, 0.5));
    let mut ws = Workspace::new(&p, 10);
    let observed = Observation::new(&x, &mask, [1, 6, 10]).unwrap();
    let prepared = auto.prepare(&observed).unwrap();
    let mut a = vec![0.0f32; n];
    let mut b = vec![0.0f32; n];
    auto.forward_with_workspace(&prepared, &mut ws, &x, 3, &mut a)
        .unwrap();
    auto.forward(&x, &observed, 3, &mut b).unwrap();
    assert_eq!(a, b);
}

#[test]
fn splitting_one_forward_over_threads_gives_the_same_bits() {
    let cfg = config(5, 24, 3, 40, 2, 9, 4); // K = 15, L = 13
    let d = model(&cfg, 61);
    let (k, l) = (15usize, 13usize);
    let n = k * l;
    let (x, obs, mask) = (values(n, 1, 1.0), values(n, 2, 1.0), binary_mask(n, 3, 0.5));
    let prepared = d
        .prepare(&Observation::new(&obs, &mask, [1, k, l]).unwrap())
        .unwrap();
    let mut outs = Vec::new();
    for threads in [1usize, 2, 3, 7, 40] {
        let mut ws = Workspace::with_threads(&d, l, threads);
        let mut o = vec![0.0f32; n];
        tcd_core::with_threads(Some(threads.min(4)), || {
            d.forward_with_workspace(&prepared, &mut ws, &x, 4, &mut o)
                .unwrap()
        })
        .unwrap();
        outs.push(o);
    }
    for o in &outs[1..] {
        assert_eq!(o, &outs[0]);
    }
}
