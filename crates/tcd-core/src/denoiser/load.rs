//! Loading a [`Denoiser`]: the weight file's tensors into layers, the step embedding and every
//! block's diffusion projection tabulated for all T steps, the cond projection split for
//! hoisting, and the kernel chosen (weights packed for it).

use super::packed::FastModel;
use super::{Denoiser, ResidualLayer};
use crate::config::TcdConfig;
use crate::error::Result;
use crate::kernels::{Isa, Kernel};
use crate::nn::activation::{map_inplace, silu};
use crate::nn::embedding::step_embedding_table;
use crate::nn::{EncoderLayer, Linear};
use crate::weights::{Network, Source, Weights};

/// The denoiser's file: the `state_dict` of TCD_REFERENCE.md 10.1 (K = num_features, E =
/// feature_embedding_dim, D = diffusion_embedding_dim, C = channels, S = side_dim, F = ffn_dim; the
/// Conv1d weights keep their kernel dimension of 1).
impl Network for Denoiser {
    type Config = TcdConfig;

    fn source(&self) -> &Source<TcdConfig> {
        &self.source
    }

    fn build(w: &mut Weights<'_>, source: Source<TcdConfig>) -> Result<Self> {
        let config = &source.config;
        let m = &config.model;
        let (k, c, d, e, te) = (
            m.num_features,
            m.channels,
            m.diffusion_embedding_dim,
            m.feature_embedding_dim,
            m.time_embedding_dim,
        );
        let num_steps = config.diffusion.num_train_timesteps;

        let feature_embedding = w.take("embed_layer.weight", &[k, e])?;
        let input_projection = Linear::load_conv(w, "diffmodel.input_projection", c, 2)?;
        let projection1 = Linear::load(w, "diffmodel.diffusion_embedding.projection1", d, d)?;
        let projection2 = Linear::load(w, "diffmodel.diffusion_embedding.projection2", d, d)?;
        let output_projection1 = Linear::load_conv(w, "diffmodel.output_projection1", c, c)?;
        let output_projection2 = Linear::load_conv(w, "diffmodel.output_projection2", 1, c)?;

        // Step embedding e_t = SiLU(P2 · SiLU(P1 · table[t])) for every t.
        let table = step_embedding_table(num_steps, d);
        let mut hidden = vec![0.0f32; num_steps * d];
        projection1.forward(&table, &mut hidden);
        map_inplace(&mut hidden, silu);
        let mut step_embedding = vec![0.0f32; num_steps * d];
        projection2.forward(&hidden, &mut step_embedding);
        map_inplace(&mut step_embedding, silu);

        let num_layers = m.num_layers;
        let mut step_bias = vec![0.0f32; num_steps * num_layers * c];
        let mut layers = Vec::with_capacity(num_layers);
        for i in 0..num_layers {
            let p = format!("diffmodel.residual_layers.{i}");
            let diffusion_projection = Linear::load(w, &format!("{p}.diffusion_projection"), c, d)?;
            for t in 0..num_steps {
                let off = (t * num_layers + i) * c;
                diffusion_projection.forward(
                    &step_embedding[t * d..(t + 1) * d],
                    &mut step_bias[off..off + c],
                );
            }
            // cond_projection (2C, S, 1): columns [time (te) | feature (E) | mask (1)].
            let s = m.side_dim;
            let cw = w.take(&format!("{p}.cond_projection.weight"), &[2 * c, s, 1])?;
            let cb = w.take(&format!("{p}.cond_projection.bias"), &[2 * c])?;
            let time_cols: Vec<f32> = cw
                .chunks_exact(s)
                .flat_map(|row| row[..te].iter().copied())
                .collect();
            let cond_time = Linear::from_torch(2 * c, te, &time_cols, &cb)?;
            let cond_mask: Vec<f32> = cw.chunks_exact(s).map(|row| row[te + e]).collect();
            let mut cond_feature = vec![0.0f32; k * 2 * c];
            for (kk, emb) in feature_embedding.chunks_exact(e).enumerate() {
                for (o, row) in cw.chunks_exact(s).enumerate() {
                    let wf = &row[te..te + e];
                    cond_feature[kk * 2 * c + o] = wf.iter().zip(emb).map(|(a, b)| a * b).sum();
                }
            }
            layers.push(ResidualLayer {
                time_layer: EncoderLayer::load(w, &format!("{p}.time_layer.layers.0"), m)?,
                feature_layer: EncoderLayer::load(w, &format!("{p}.feature_layer.layers.0"), m)?,
                mid_projection: Linear::load_conv(w, &format!("{p}.mid_projection"), 2 * c, c)?,
                output_projection: Linear::load_conv(
                    w,
                    &format!("{p}.output_projection"),
                    2 * c,
                    c,
                )?,
                cond_time,
                cond_feature,
                cond_mask,
            });
        }
        let schedule = config.schedule();
        let kernel = Kernel::from_env()?;
        Denoiser {
            source,
            schedule,
            input_projection,
            step_embedding,
            step_bias,
            layers,
            output_projection1,
            output_projection2,
            kernel: Kernel::Portable,
            fast: None,
        }
        .with_kernel(kernel)
    }
}

impl Denoiser {
    /// The same model running `kernel` (`Auto`: the best this CPU supports). Errors if the CPU
    /// does not support the kernel. Packs the weights for it once.
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self> {
        let kernel = kernel.resolve()?;
        self.fast = Isa::for_kernel(kernel).map(|isa| FastModel::new(isa, &self));
        self.kernel = kernel;
        Ok(self)
    }
}
