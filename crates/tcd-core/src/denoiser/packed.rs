//! One sequence through the network on the SIMD kernels of [`crate::kernels`]: the weights
//! packed at load ([`FastModel`]) and the forward that runs on them.

use rayon::prelude::*;

use super::forward::SequenceInputs;
use super::input::build_input;
use super::workspace::Workspace;
use super::Denoiser;
use crate::kernels::{
    self, Epilogue, FastEncoder, FastLinear, Isa, Matrix, MatrixMut, SeqLayout, TailInputs,
    TailStreams,
};
use crate::nn::activation::map_inplace;

/// A residual block with weights packed for the SIMD kernels.
#[derive(Clone, Debug)]
struct FastBlock {
    time: FastEncoder,
    feature: FastEncoder,
    mid: FastLinear,
    out: FastLinear,
}

/// The weights packed for the SIMD kernels of one instruction set.
#[derive(Clone, Debug)]
pub(super) struct FastModel {
    isa: Isa,
    input: FastLinear,
    out1: FastLinear,
    blocks: Vec<FastBlock>,
}

impl FastModel {
    pub(super) fn new(isa: Isa, d: &Denoiser) -> FastModel {
        FastModel {
            isa,
            input: FastLinear::new(isa, &d.input_projection),
            out1: FastLinear::new(isa, &d.output_projection1),
            blocks: d
                .layers
                .iter()
                .map(|l| FastBlock {
                    time: FastEncoder::new(isa, &l.time_layer),
                    feature: FastEncoder::new(isa, &l.feature_layer),
                    mid: FastLinear::new(isa, &l.mid_projection),
                    out: FastLinear::new(isa, &l.output_projection),
                })
                .collect(),
        }
    }
}

impl Denoiser {
    /// [`Denoiser::forward_one`] on the SIMD kernels.
    pub(super) fn forward_sequence_fast(
        &self,
        fast: &FastModel,
        seq: SequenceInputs<'_>,
        out: &mut [f32],
        ws: &mut Workspace,
    ) {
        let SequenceInputs {
            tables,
            mask,
            noisy,
            observed,
            step,
        } = seq;
        let m = &self.source.config.model;
        let (k, l, c) = (m.num_features, tables.length, m.channels);
        let n = k * l;
        let num_layers = self.layers.len();
        let isa = fast.isa;
        let Workspace {
            h,
            y,
            z,
            skip,
            fast: scratch,
            ..
        } = ws;
        let parts = scratch.len();

        let inp = &mut z[..2 * n];
        build_input(m.cond_fill, l, mask, observed, noisy, inp);
        kernels::gemm(
            isa,
            Matrix::dense(inp, n, 2),
            &fast.input,
            MatrixMut::dense(h, n, c),
            Epilogue::Relu,
        );
        skip.fill(0.0);
        let bias = |i: usize| {
            let off = (step * num_layers + i) * c;
            &self.step_bias[off..off + c]
        };
        if num_layers > 0 {
            let dp = bias(0);
            for (yr, hr) in y.chunks_exact_mut(c).zip(h.chunks_exact(c)) {
                for ((yv, hv), dv) in yr.iter_mut().zip(hr).zip(dp) {
                    *yv = hv + dv;
                }
            }
        }
        for (i, (layer, block)) in self.layers.iter().zip(&fast.blocks).enumerate() {
            if l > 1 {
                let layout = SeqLayout {
                    num_seq: k,
                    seq_len: l,
                    seq_stride: l * c,
                    tok_stride: c,
                };
                kernels::encoder_par(isa, &block.time, y, layout, scratch);
            }
            if k > 1 {
                let layout = SeqLayout {
                    num_seq: l,
                    seq_len: k,
                    seq_stride: c,
                    tok_stride: l * c,
                };
                kernels::encoder_par(isa, &block.feature, y, layout, scratch);
            }
            let inputs = TailInputs {
                mid: &block.mid,
                out: &block.out,
                mask,
                time_tab: &tables.time[i],
                cond_feature: &layer.cond_feature,
                cond_mask: &layer.cond_mask,
                next_bias: (i + 1 < num_layers).then(|| bias(i + 1)),
                frames: l,
                channels: c,
            };
            if parts <= 1 {
                kernels::block_tail(isa, &inputs, 0, TailStreams { y, h, skip }, &mut scratch[0]);
            } else {
                // Contiguous coordinate ranges per worker.
                let per = k.div_ceil(parts) * l * c;
                y.par_chunks_mut(per)
                    .zip(h.par_chunks_mut(per))
                    .zip(skip.par_chunks_mut(per))
                    .zip(scratch.par_iter_mut())
                    .enumerate()
                    .for_each(|(p, (((y, h), skip), sc))| {
                        kernels::block_tail(
                            isa,
                            &inputs,
                            p * (per / (l * c)),
                            TailStreams { y, h, skip },
                            sc,
                        );
                    });
            }
        }
        let sqrt_layers = (num_layers as f64).sqrt() as f32;
        map_inplace(skip, |v| v / sqrt_layers);
        // y = ReLU(skip · out1) over the rows of `s`, those of `yc`.
        let out1 = |s: &[f32], yc: &mut [f32]| {
            let rows = s.len() / c;
            kernels::gemm(
                isa,
                Matrix::dense(s, rows, c),
                &fast.out1,
                MatrixMut::dense(yc, rows, c),
                Epilogue::Relu,
            );
        };
        if parts <= 1 {
            out1(&skip[..n * c], y);
        } else {
            let per = k.div_ceil(parts) * l * c;
            skip.par_chunks(per)
                .zip(y.par_chunks_mut(per))
                .for_each(|(s, yc)| out1(s, yc));
        }
        self.output_projection2.forward(y, &mut out[..n]);
    }
}
