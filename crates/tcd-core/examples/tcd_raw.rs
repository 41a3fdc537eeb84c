//! A tiny command line over the engine with raw little-endian f32 files, for parity checks from
//! any language (numpy: `a.astype('<f4').tofile(path)` / `np.fromfile(path, '<f4')`).
//!
//! ```text
//! tcd_raw info    WEIGHTS
//! tcd_raw forward WEIGHTS NOISY OBSERVED MASK B L STEP OUT            arrays (B, K, L)
//! tcd_raw sample  WEIGHTS OBSERVED MASK B L S SAMPLER N ETA SPACING NOISE|seed:N OUT
//!                 SAMPLER ddpm|ddim|dpmpp2m, N steps or `all`; NOISE (S, N+1, B, K, L) ((S, 1, B, K, L) for dpmpp2m); OUT (S, B, K, L)
//! tcd_raw cascade SHORT LONG OBSERVED MASK B S SAMPLER N ETA SPACING seed:N OUT_PREFIX
//!                 OBSERVED/MASK (B, K, O); writes OUT_PREFIX{mean,samples,repaired,short_mean}.f32
//! tcd_raw noise   SEED STAGE S BLOCKS B BLOCK_LEN OUT                 the seeded streams, (S, BLOCKS, B, BLOCK_LEN)
//! ```

use std::error::Error;
use std::path::Path;

use tcd_core::{
    cascade, sample, CascadeNoise, Control, Denoiser, ForecastOptions, Noise, Observation,
    SamplerConfig, SamplerKind, Sequences,
};
use tcd_core::{seeded_noise, Network};

type R<T> = Result<T, Box<dyn Error>>;

fn read_f32(path: &str) -> R<Vec<f32>> {
    let bytes = std::fs::read(path)?;
    if bytes.len() % 4 != 0 {
        return Err(format!("{path}: size {} is not a multiple of 4", bytes.len()).into());
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect())
}

fn write_f32(path: impl AsRef<Path>, data: &[f32]) -> R<()> {
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(path, bytes)?;
    Ok(())
}

fn num<T: std::str::FromStr>(args: &[String], i: usize, what: &str) -> R<T> {
    args.get(i)
        .ok_or_else(|| format!("missing argument {what}"))?
        .parse::<T>()
        .map_err(|_| format!("argument {what} is not a number: {:?}", args.get(i)).into())
}

fn arg<'a>(args: &'a [String], i: usize, what: &str) -> R<&'a str> {
    Ok(args
        .get(i)
        .ok_or_else(|| format!("missing argument {what}"))?
        .as_str())
}

/// The arrays OBSERVED and MASK, read from the files named by `args[i]` and `args[i + 1]`.
fn observation_args(args: &[String], i: usize) -> R<(Vec<f32>, Vec<f32>)> {
    Ok((
        read_f32(arg(args, i, "OBSERVED")?)?,
        read_f32(arg(args, i + 1, "MASK")?)?,
    ))
}

/// The sampler of SAMPLER N ETA SPACING, `args[i..i + 4]`.
fn sampler_args(args: &[String], i: usize) -> R<SamplerConfig> {
    sampler(
        arg(args, i, "SAMPLER")?,
        arg(args, i + 1, "N")?,
        num(args, i + 2, "ETA")?,
        arg(args, i + 3, "SPACING")?,
    )
}

fn sampler(kind: &str, steps: &str, eta: f64, spacing: &str) -> R<SamplerConfig> {
    let kind = match kind {
        "ddpm" => SamplerKind::Ddpm,
        "ddim" => SamplerKind::Ddim { eta },
        "dpmpp2m" => SamplerKind::DpmPp2m,
        other => return Err(format!("sampler must be ddpm, ddim or dpmpp2m, got {other}").into()),
    };
    let num_inference_steps = if steps == "all" {
        None
    } else {
        Some(steps.parse()?)
    };
    Ok(SamplerConfig {
        kind,
        num_inference_steps,
        timestep_spacing: spacing.parse()?,
        ..SamplerConfig::default()
    })
}

fn seed_of(s: &str) -> Option<u64> {
    s.strip_prefix("seed:").and_then(|v| v.parse().ok())
}

fn main() -> R<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("info") => {
            let d = Denoiser::load(arg(&args, 1, "WEIGHTS")?)?;
            println!("{}", d.config_json());
        }
        Some("forward") => {
            let d = Denoiser::load(arg(&args, 1, "WEIGHTS")?)?;
            let noisy = read_f32(arg(&args, 2, "NOISY")?)?;
            let (observed, mask) = observation_args(&args, 3)?;
            let (b, l, step): (usize, usize, usize) = (
                num(&args, 5, "B")?,
                num(&args, 6, "L")?,
                num(&args, 7, "STEP")?,
            );
            let mut out = vec![0.0f32; noisy.len()];
            let observed = Observation::new(&observed, &mask, [b, d.num_features(), l])?;
            d.forward(&noisy, &observed, step, &mut out)?;
            write_f32(arg(&args, 8, "OUT")?, &out)?;
        }
        Some("sample") => {
            let d = Denoiser::load(arg(&args, 1, "WEIGHTS")?)?;
            let (observed, mask) = observation_args(&args, 2)?;
            let (b, l, s): (usize, usize, usize) = (
                num(&args, 4, "B")?,
                num(&args, 5, "L")?,
                num(&args, 6, "S")?,
            );
            let cfg = sampler_args(&args, 7)?;
            let src = arg(&args, 11, "NOISE")?;
            let data;
            let noise = match seed_of(src) {
                Some(seed) => Noise::seeded(seed),
                None => {
                    data = read_f32(src)?;
                    Noise::Injected(&data)
                }
            };
            let out = sample(
                &d,
                &Observation::new(&observed, &mask, [b, d.num_features(), l])?,
                s,
                &cfg,
                noise,
                &Control::default(),
            )?;
            write_f32(arg(&args, 12, "OUT")?, &out)?;
        }
        Some("cascade") => {
            let short = Denoiser::load(arg(&args, 1, "SHORT")?)?;
            let long = Denoiser::load(arg(&args, 2, "LONG")?)?;
            let (observed, mask) = observation_args(&args, 3)?;
            let (b, s): (usize, usize) = (num(&args, 5, "B")?, num(&args, 6, "S")?);
            let cfg = sampler_args(&args, 7)?;
            let seed = seed_of(arg(&args, 11, "seed:N")?).ok_or("the cascade takes seed:N")?;
            let opts = ForecastOptions {
                num_samples: s,
                sampler: cfg,
            };
            let out = cascade(
                &short,
                &long,
                None,
                &Observation::new(&observed, &mask, [b, short.num_features(), short.obs_len()])?,
                &opts,
                CascadeNoise::seeded(seed, Sequences::From(0)),
                &Control::default(),
            )?;
            let prefix = arg(&args, 12, "OUT_PREFIX")?;
            write_f32(format!("{prefix}mean.f32"), &out.mean)?;
            write_f32(format!("{prefix}samples.f32"), &out.samples)?;
            write_f32(format!("{prefix}repaired.f32"), &out.repaired)?;
            write_f32(format!("{prefix}short_mean.f32"), &out.short_mean)?;
        }
        Some("noise") => {
            let seed: u64 = num(&args, 1, "SEED")?;
            let stage: u64 = num(&args, 2, "STAGE")?;
            let (s, blocks, b, len): (usize, usize, usize, usize) = (
                num(&args, 3, "S")?,
                num(&args, 4, "BLOCKS")?,
                num(&args, 5, "B")?,
                num(&args, 6, "BLOCK_LEN")?,
            );
            write_f32(
                arg(&args, 7, "OUT")?,
                &seeded_noise(seed, Sequences::From(0), stage, s, blocks, b, len),
            )?;
        }
        _ => {
            eprintln!(
                "usage: tcd_raw info|forward|sample|cascade|noise ... (see the source header)"
            );
            std::process::exit(2);
        }
    }
    Ok(())
}
