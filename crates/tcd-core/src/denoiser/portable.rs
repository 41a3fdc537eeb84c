//! One sequence through the network on the portable layers of [`crate::nn`] (the reference
//! implementation; any target).

use super::forward::SequenceInputs;
use super::input::build_input;
use super::workspace::Workspace;
use super::Denoiser;
use crate::nn::activation::{map_inplace, relu, sigmoid};

impl Denoiser {
    /// [`Denoiser::forward_one`] on the portable layers.
    pub(super) fn forward_sequence_portable(
        &self,
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
        let c2 = 2 * c;
        let num_layers = self.layers.len();
        let Workspace {
            h,
            y,
            yt,
            z,
            g,
            skip,
            scratch,
            ..
        } = ws;

        // Input: channel 0 = the observed channel, channel 1 = (1−m)·x_t; h = ReLU(input_projection) (N × C).
        let inp = &mut z[..2 * n];
        build_input(m.cond_fill, l, mask, observed, noisy, inp);
        self.input_projection.forward(inp, h);
        map_inplace(h, relu);
        skip.fill(0.0);

        let sqrt2 = std::f64::consts::SQRT_2 as f32;
        for (i, layer) in self.layers.iter().enumerate() {
            // y = h + diffusion_projection(e_t), broadcast over the N tokens.
            let off = (step * num_layers + i) * c;
            let dp = &self.step_bias[off..off + c];
            for (yr, hr) in y.chunks_exact_mut(c).zip(h.chunks_exact(c)) {
                for ((yv, hv), dv) in yr.iter_mut().zip(hr).zip(dp) {
                    *yv = hv + dv;
                }
            }
            // Temporal transformer: K sequences of L tokens (contiguous in token-major layout).
            if l > 1 {
                layer.time_layer.forward(y, l, scratch);
            }
            // Feature transformer: L sequences of K tokens, on a (L × K × C) transposed copy.
            if k > 1 {
                transpose_tokens(y, yt, k, l, c);
                layer.feature_layer.forward(yt, k, scratch);
                transpose_tokens(yt, y, l, k, c);
            }
            // z = mid_projection(y) + cond_projection(side)  (N × 2C)
            layer.mid_projection.forward(y, z);
            let time_tab = &tables.time[i];
            for (kk, zk) in z.chunks_exact_mut(l * c2).enumerate() {
                let ft = &layer.cond_feature[kk * c2..(kk + 1) * c2];
                for (ll, zr) in zk.chunks_exact_mut(c2).enumerate() {
                    let tt = &time_tab[ll * c2..(ll + 1) * c2];
                    let mv = mask[kk * l + ll];
                    for (((zv, tv), fv), wv) in zr.iter_mut().zip(tt).zip(ft).zip(&layer.cond_mask)
                    {
                        *zv += tv + fv + mv * wv;
                    }
                }
            }
            // g = sigmoid(gate) · tanh(filter), gate = first C channels.
            for (gr, zr) in g.chunks_exact_mut(c).zip(z.chunks_exact(c2)) {
                let (gate, filter) = zr.split_at(c);
                for ((gv, a), f) in gr.iter_mut().zip(gate).zip(filter) {
                    *gv = sigmoid(*a) * f.tanh();
                }
            }
            // [residual | skip] = output_projection(g); h = (h + residual)/√2; Σskip += skip.
            layer.output_projection.forward(g, z);
            for ((hr, sr), zr) in h
                .chunks_exact_mut(c)
                .zip(skip.chunks_exact_mut(c))
                .zip(z.chunks_exact(c2))
            {
                let (res, sk) = zr.split_at(c);
                for (hv, rv) in hr.iter_mut().zip(res) {
                    *hv = (*hv + rv) / sqrt2;
                }
                for (sv, kv) in sr.iter_mut().zip(sk) {
                    *sv += kv;
                }
            }
        }
        // out = output_projection2(ReLU(output_projection1(Σskip / √N_layers)))  → (K, L)
        let sqrt_layers = (num_layers as f64).sqrt() as f32;
        map_inplace(skip, |v| v / sqrt_layers);
        self.output_projection1.forward(skip, y);
        map_inplace(y, relu);
        self.output_projection2.forward(y, &mut out[..n]);
    }
}

/// (A × B × C) → (B × A × C): moves token rows, C values each.
fn transpose_tokens(src: &[f32], dst: &mut [f32], a: usize, b: usize, c: usize) {
    for (ia, block) in src.chunks_exact(b * c).take(a).enumerate() {
        for (ib, row) in block.chunks_exact(c).enumerate() {
            let o = (ib * a + ia) * c;
            dst[o..o + c].copy_from_slice(row);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::transpose_tokens;

    #[test]
    fn transpose_round_trip() {
        let (a, b, c) = (3, 4, 2);
        let src: Vec<f32> = (0..a * b * c).map(|v| v as f32).collect();
        let mut t = vec![0.0; a * b * c];
        let mut back = vec![0.0; a * b * c];
        transpose_tokens(&src, &mut t, a, b, c);
        // element (ia=1, ib=2, ch=1) goes to (ib=2, ia=1, ch=1)
        assert_eq!(t[(2 * a + 1) * c + 1], src[(b + 2) * c + 1]);
        transpose_tokens(&t, &mut back, b, a, c);
        assert_eq!(src, back);
    }
}
