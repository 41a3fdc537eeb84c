//! Median time of one denoiser forward (batch 1) per kernel, prepared tables and workspace reused:
//!
//! ```text
//! cargo run --release --example bench_forward -- WEIGHTS [REPS] [KERNEL ...]
//! ```
//! KERNEL: portable, avx2, avx512 (default: every one this CPU supports). WEIGHTS may also be
//! `paper55` / `paper75`: random-init weights of the paper's size (12 layers × 64 channels, 8 heads,
//! K = 66) for L = 55 / 75, built in-process; `paper75h4` etc. with another head count.
//! `TCD_BENCH_THREADS=N` splits one forward over N threads.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, dead_code)]

#[path = "../tests/common/mod.rs"]
mod common;

use std::error::Error;
use std::time::Instant;
use tcd_core::FileConfig;

use tcd_core::{Denoiser, Kernel, Network, Observation, Role, Workspace};

/// Random-init weights of the paper's size (with `heads` attention heads) for windows of `obs` +
/// `pred` frames.
fn paper_model(obs: usize, pred: usize, heads: usize) -> Result<Denoiser, Box<dyn Error>> {
    let mut cfg = common::tiny_config(Role::Long, obs, pred);
    let m = &mut cfg.model;
    (
        m.num_joints,
        m.num_features,
        m.channels,
        m.num_heads,
        m.ffn_dim,
        m.num_layers,
    ) = (22, 66, 64, heads, 64, 12);
    (
        m.diffusion_embedding_dim,
        m.time_embedding_dim,
        m.feature_embedding_dim,
    ) = (128, 128, 16);
    m.side_dim = 128 + 16 + 1;
    let bytes = common::serialize(&common::random_tensors(&cfg, 1), Some(cfg.to_json()));
    Ok(Denoiser::from_bytes(&bytes, "paper.safetensors")?)
}

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .ok_or("usage: bench_forward WEIGHTS [REPS] [KERNEL ...]")?;
    let reps: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(15);
    let kernels: Vec<Kernel> = if args.len() > 2 {
        args[2..]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?
    } else {
        Kernel::supported()
    };
    // paper55 / paper75, optionally with a head count: paper75h4 (head dim 16).
    let paper = path.strip_prefix("paper").and_then(|rest| {
        let (len, heads) = rest.split_once('h').unwrap_or((rest, "8"));
        Some((len.parse::<usize>().ok()?, heads.parse::<usize>().ok()?))
    });
    let base = match paper {
        Some((55, heads)) => paper_model(50, 5, heads)?,
        Some((75, heads)) => paper_model(55, 20, heads)?,
        _ => Denoiser::load(path)?,
    };
    let threads: usize = std::env::var("TCD_BENCH_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let (k, l) = (base.num_features(), base.seq_len());
    let step = 25.min(base.num_train_timesteps() - 1);
    let n = k * l;
    let noisy: Vec<f32> = (0..n)
        .map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0)
        .collect();
    let observed: Vec<f32> = (0..n)
        .map(|i| ((i * 53 % 89) as f32 / 89.0) - 0.5)
        .collect();
    let mask: Vec<f32> = (0..n)
        .map(|i| if i % l < base.obs_len() { 1.0 } else { 0.0 })
        .collect();
    let mut reference: Option<Vec<f32>> = None;
    for kernel in kernels {
        let d = base.clone().with_kernel(kernel)?;
        let prepared = d.prepare(&Observation::new(&observed, &mask, [1, k, l])?)?;
        let mut ws = Workspace::with_threads(&d, l, threads);
        let mut out = vec![0.0f32; n];
        pool.install(|| d.forward_with_workspace(&prepared, &mut ws, &noisy, step, &mut out))?;
        let diff = reference.as_ref().map(|r| {
            r.iter()
                .zip(&out)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max)
        });
        if reference.is_none() {
            reference = Some(out.clone());
        }
        let mut times = Vec::with_capacity(reps);
        let cpu0 = thread_cpu_ns();
        for _ in 0..reps {
            let t0 = Instant::now();
            pool.install(|| d.forward_with_workspace(&prepared, &mut ws, &noisy, step, &mut out))?;
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        let cpu_ms = thread_cpu_ns()
            .zip(cpu0)
            .map(|(b, a)| (b - a) as f64 / 1e6 / reps as f64);
        times.sort_by(|a, b| a.total_cmp(b));
        println!(
            "L={l} K={k} kernel={kernel}: median {:.2} ms, min {:.2} ms, this thread's CPU time {:.2} ms/forward, threads {}{}",
            times[reps / 2],
            times[0],
            cpu_ms.unwrap_or(f64::NAN),
            threads,
            diff.map(|d| format!(", max |diff| vs first {d:e}")).unwrap_or_default()
        );
    }
    Ok(())
}

/// CPU time of the calling thread in ns (Linux `/proc/thread-self/schedstat`), if available: a
/// timing that is robust to other processes competing for the cores.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}
