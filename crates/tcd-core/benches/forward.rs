//! Criterion benchmarks of the kernels: one denoiser forward (batch 1, K = 66) per kernel path the
//! CPU supports, at the bundled reduced size (3 layers × 32 channels) and the paper's size (12 × 64),
//! L = 55 and 75, on one thread and split over two.
//!
//!     cargo bench -p tcd-core --bench forward            # measure
//!     cargo test  -p tcd-core --benches                  # smoke: every benchmark runs once
//!
//! Random-init weights (the cost does not depend on the values). Timings on a shared machine are
//! noisy: compare kernels within one run.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, dead_code)]

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use tcd_core::FileConfig;
use tcd_core::{Denoiser, Kernel, Network, Observation, Role, TcdConfig, Workspace};

fn config(
    channels: usize,
    heads: usize,
    ffn: usize,
    layers: usize,
    obs: usize,
    pred: usize,
) -> TcdConfig {
    let mut cfg = common::tiny_config(Role::Long, obs, pred);
    let m = &mut cfg.model;
    m.num_joints = 22;
    m.num_features = 66;
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

fn bench_forward(c: &mut Criterion) {
    let sizes = [
        ("reduced_3x32", 32, 4, 32, 3),
        ("paper_12x64", 64, 8, 64, 12),
    ];
    for (name, ch, heads, ffn, layers) in sizes {
        let mut group = c.benchmark_group(format!("forward_{name}"));
        group.sample_size(10);
        for (obs, pred) in [(50usize, 5usize), (55, 20)] {
            let cfg = config(ch, heads, ffn, layers, obs, pred);
            let bytes = common::serialize(&common::random_tensors(&cfg, 1), Some(cfg.to_json()));
            let base = Denoiser::from_bytes(&bytes, "bench.safetensors").unwrap();
            let (k, l) = (66usize, obs + pred);
            let n = k * l;
            let noisy = common::values(n, 2, 1.0);
            let observed = common::values(n, 3, 0.3);
            let mut mask = vec![0.0f32; n];
            for (i, m) in mask.iter_mut().enumerate() {
                *m = if i % l < 50 { 1.0 } else { 0.0 };
            }
            for kernel in Kernel::supported() {
                let den = base.clone().with_kernel(kernel).unwrap();
                let prepared = den
                    .prepare(&Observation::new(&observed, &mask, [1, k, l]).unwrap())
                    .unwrap();
                for threads in [1usize, 2] {
                    let mut out = vec![0.0f32; n];
                    let id = BenchmarkId::new(format!("{kernel}/{threads}t"), format!("L{l}"));
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let mut ws = Workspace::with_threads(&den, l, threads);
                    group.bench_function(id, |b| {
                        b.iter(|| {
                            pool.install(|| {
                                den.forward_with_workspace(&prepared, &mut ws, &noisy, 5, &mut out)
                                    .unwrap()
                            })
                        })
                    });
                }
            }
        }
        group.finish();
    }
}

criterion_group!(benches, bench_forward);
criterion_main!(benches);
