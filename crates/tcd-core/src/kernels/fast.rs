//! The fast path's safe layer: weights packed for the SIMD GEMM ([`Packed`], [`FastLinear`],
//! [`FastEncoder`]), per-worker scratch, the token layouts the kernels take, and the dispatchers,
//! which check every size and stride against the slices before calling the kernel of the detected
//! instruction set.

#[cfg(target_arch = "x86_64")]
use super::x86;
use super::{Isa, IsaKind};
use crate::nn::attention::HeadScratch;
use crate::nn::{EncoderLayer, Linear};

/// A weight matrix packed for the SIMD GEMM: Wᵀ (in × out) cut into panels of `pw` output
/// columns, each stored contiguously (in × pw), the last one zero-padded; the bias padded alike.
#[derive(Clone, Debug)]
pub(crate) struct Packed {
    pub(super) in_dim: usize,
    pub(super) out_dim: usize,
    /// Panel width in floats (vectors per panel × lanes).
    pub(super) pw: usize,
    pub(super) panels: usize,
    pub(super) w: Vec<f32>,
    pub(super) b: Vec<f32>,
}

impl Packed {
    fn new(isa: Isa, lin: &Linear) -> Packed {
        let (in_dim, out_dim) = (lin.in_dim(), lin.out_dim());
        let pw = isa.panel_vectors(out_dim) * isa.lanes();
        let panels = out_dim.div_ceil(pw);
        let mut w = vec![0.0f32; panels * in_dim * pw];
        let mut b = vec![0.0f32; panels * pw];
        for o in 0..out_dim {
            let (p, j) = (o / pw, o % pw);
            for i in 0..in_dim {
                w[(p * in_dim + i) * pw + j] = lin.weight(o, i);
            }
        }
        b[..out_dim].copy_from_slice(lin.bias());
        Packed {
            in_dim,
            out_dim,
            pw,
            panels,
            w,
            b,
        }
    }
}

/// One transformer encoder layer with packed weights.
#[derive(Clone, Debug)]
pub(crate) struct FastEncoder {
    pub(super) c: usize,
    pub(super) f: usize,
    pub(super) heads: usize,
    pub(super) qkv: Packed,
    pub(super) out: Packed,
    pub(super) ff1: Packed,
    pub(super) ff2: Packed,
    pub(super) ln1: (Vec<f32>, Vec<f32>, f32),
    pub(super) ln2: (Vec<f32>, Vec<f32>, f32),
}

impl FastEncoder {
    pub(crate) fn new(isa: Isa, layer: &EncoderLayer) -> FastEncoder {
        let attn = layer.self_attn();
        let (l1, l2) = layer.feed_forward();
        let (n1, n2) = layer.norms();
        FastEncoder {
            c: attn.channels(),
            f: l1.out_dim(),
            heads: attn.num_heads(),
            qkv: Packed::new(isa, attn.in_proj()),
            out: Packed::new(isa, attn.out_proj()),
            ff1: Packed::new(isa, l1),
            ff2: Packed::new(isa, l2),
            ln1: (n1.weight().to_vec(), n1.bias().to_vec(), n1.eps()),
            ln2: (n2.weight().to_vec(), n2.bias().to_vec(), n2.eps()),
        }
    }
}

/// A dense layer packed for the fast path (the denoiser's convolutions and projections).
#[derive(Clone, Debug)]
pub(crate) struct FastLinear(pub(super) Packed);

impl FastLinear {
    pub(crate) fn new(isa: Isa, lin: &Linear) -> FastLinear {
        FastLinear(Packed::new(isa, lin))
    }
}

/// What the GEMM does with `x · W + b` before it lands in `y`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Epilogue {
    /// y = x·W + b
    Store,
    /// y = max(x·W + b, 0)
    Relu,
    /// y = gelu_erf(x·W + b)
    Gelu,
    /// y = y + (x·W + b)
    AddTo,
}

/// Scratch of the fast path for one worker: sized for sequences of up to `len` tokens.
#[derive(Clone, Debug, Default)]
pub(crate) struct FastScratch {
    pub(super) qkv: Vec<f32>,
    pub(super) heads: Vec<f32>,
    pub(super) ffn: Vec<f32>,
    /// Attention scores of one query block (len × 16).
    pub(super) scores: Vec<f32>,
    /// Portable-attention fallback (head dims other than 4, 8, 16).
    pub(super) portable: HeadScratch,
    /// Residual-block tail: (L × 2C) and (L × C).
    pub(super) zt: Vec<f32>,
    pub(super) gt: Vec<f32>,
}

impl FastScratch {
    pub(crate) fn new(c: usize, f: usize, len: usize, frames: usize) -> FastScratch {
        FastScratch {
            qkv: vec![0.0; len * 3 * c],
            heads: vec![0.0; len * c],
            ffn: vec![0.0; len * f],
            scores: vec![0.0; len * 16],
            portable: HeadScratch::new(c, len),
            zt: vec![0.0; frames * 2 * c],
            gt: vec![0.0; frames * c],
        }
    }
}

/// Where the tokens of a batch of sequences lie in a buffer of C-vectors: sequence `s`, token
/// `t` starts at `s · seq_stride + t · tok_stride`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SeqLayout {
    pub num_seq: usize,
    pub seq_len: usize,
    pub seq_stride: usize,
    pub tok_stride: usize,
}

/// A row-major matrix in a slice: `rows` rows of `cols` values, row `r` at `data[r · ld ..]`
/// (`ld ≥ cols`; the dispatcher that takes it checks it against the slice).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Matrix<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub ld: usize,
}

impl<'a> Matrix<'a> {
    /// `rows` × `cols`, rows contiguous (`ld = cols`).
    pub(crate) fn dense(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Matrix {
            data,
            rows,
            cols,
            ld: cols,
        }
    }
}

/// [`Matrix`], writable.
#[derive(Debug)]
pub(crate) struct MatrixMut<'a> {
    pub data: &'a mut [f32],
    pub rows: usize,
    pub cols: usize,
    pub ld: usize,
}

impl<'a> MatrixMut<'a> {
    /// `rows` × `cols`, rows contiguous (`ld = cols`).
    pub(crate) fn dense(data: &'a mut [f32], rows: usize, cols: usize) -> Self {
        MatrixMut {
            data,
            rows,
            cols,
            ld: cols,
        }
    }
}

/// The per-block inputs of [`block_tail`], shared by the workers.
pub(crate) struct TailInputs<'a> {
    pub mid: &'a FastLinear,
    pub out: &'a FastLinear,
    /// (K × L) mask of the sequence.
    pub mask: &'a [f32],
    /// (L × 2C) time part of the cond projection, with its bias.
    pub time_tab: &'a [f32],
    /// (K × 2C) feature part of the cond projection.
    pub cond_feature: &'a [f32],
    /// (2C) mask column.
    pub cond_mask: &'a [f32],
    /// The next block's step bias (C): if given, `y = h + next_bias` is written for it.
    pub next_bias: Option<&'a [f32]>,
    /// L: tokens per coordinate.
    pub frames: usize,
    /// C.
    pub channels: usize,
}

/// The residual streams of a run of whole coordinates (each `n · L · C`, token-major) that
/// [`block_tail`] updates: the block input / next block's input `y`, the residual `h`, Σskip.
pub(crate) struct TailStreams<'a> {
    pub y: &'a mut [f32],
    pub h: &'a mut [f32],
    pub skip: &'a mut [f32],
}

// ------------------------------------------------------------------------ safe dispatchers
//
// Each dispatcher checks every size and stride against the slices (so that the unsafe kernels
// only touch memory inside them) and calls the kernel of the detected instruction set.

fn span(rows: usize, ld: usize, width: usize) -> usize {
    if rows == 0 {
        0
    } else {
        (rows - 1) * ld + width
    }
}

/// `y = epilogue(x · W + b)`, row by row: x is (rows × in), y (rows × out) of the layer `w`.
pub(crate) fn gemm(isa: Isa, x: Matrix<'_>, w: &FastLinear, y: MatrixMut<'_>, epi: Epilogue) {
    let p = &w.0;
    assert!(
        x.cols == p.in_dim && y.cols == p.out_dim && x.rows == y.rows,
        "gemm shapes"
    );
    assert!(x.ld >= x.cols && y.ld >= y.cols, "gemm strides");
    assert!(
        x.data.len() >= span(x.rows, x.ld, x.cols) && y.data.len() >= span(y.rows, y.ld, y.cols),
        "gemm sizes"
    );
    match isa.0 {
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx2 => x86::gemm_avx2(x, p, y, epi),
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx512 => x86::gemm_avx512(x, p, y, epi),
    }
}

/// The affine layer norm of the prior's blocks, taken over the `k` rows of each of the `l` columns of
/// a (K × L) sequence (the coordinates of one frame; frame fastest).
#[derive(Clone, Copy, Debug)]
pub(crate) struct ColumnNorm<'a> {
    pub k: usize,
    pub l: usize,
    /// Per-row affine weight and bias (K each).
    pub weight: &'a [f32],
    pub bias: &'a [f32],
    pub eps: f32,
}

/// `state += LN(y)·weight + bias` for every (K × L) sequence of `state` and `y`, the layer norm of
/// each column over its K rows (biased variance), in the order `state + ((y − mean)·rstd)·w + b`;
/// `stats` is 2·L floats of scratch.
pub(crate) fn column_norm_residual(
    isa: Isa,
    p: &ColumnNorm<'_>,
    state: &mut [f32],
    y: &[f32],
    stats: &mut [f32],
) {
    let size = p.k * p.l;
    assert!(
        size > 0 && state.len().is_multiple_of(size) && y.len() == state.len(),
        "column norm sizes"
    );
    assert!(
        p.weight.len() == p.k && p.bias.len() == p.k && stats.len() >= 2 * p.l,
        "column norm parameters"
    );
    match isa.0 {
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx2 => x86::column_norm_residual_avx2(p, state, y, stats),
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx512 => x86::column_norm_residual_avx512(p, state, y, stats),
    }
}

/// Checks `layout` against `x` and `scratch` for [`encoder`] / [`encoder_par`].
fn check_encoder(enc: &FastEncoder, x: &[f32], layout: SeqLayout, scratch: &FastScratch) -> bool {
    let SeqLayout {
        num_seq,
        seq_len,
        seq_stride,
        tok_stride,
    } = layout;
    let c = enc.c;
    if num_seq == 0 || seq_len == 0 {
        return false;
    }
    // Injective: either sequences are contiguous blocks of rows (time transformer) or tokens
    // are blocks of interleaved sequence rows (feature transformer).
    let blocks_of_rows = tok_stride >= c && seq_stride >= seq_len * tok_stride;
    let interleaved = seq_stride >= c && tok_stride >= num_seq * seq_stride;
    assert!(blocks_of_rows || interleaved, "encoder strides");
    let last = (num_seq - 1) * seq_stride + (seq_len - 1) * tok_stride + c;
    assert!(x.len() >= last, "encoder sizes");
    assert!(
        scratch.qkv.len() >= seq_len * 3 * c
            && scratch.heads.len() >= seq_len * c
            && scratch.ffn.len() >= seq_len * enc.f
            && scratch.scores.len() >= seq_len * 16
            && scratch.portable.fits(c, seq_len),
        "encoder scratch"
    );
    assert!(
        enc.ln1.0.len() == c
            && enc.ln1.1.len() == c
            && enc.ln2.0.len() == c
            && enc.ln2.1.len() == c
    );
    assert!(
        enc.qkv.out_dim == 3 * c
            && enc.out.in_dim == c
            && enc.ff1.in_dim == c
            && enc.ff2.out_dim == c
    );
    true
}

/// Runs one encoder layer in place on the sequences of `x` described by `layout`.
pub(crate) fn encoder(
    isa: Isa,
    enc: &FastEncoder,
    x: &mut [f32],
    layout: SeqLayout,
    scratch: &mut FastScratch,
) {
    if !check_encoder(enc, x, layout, scratch) {
        return;
    }
    match isa.0 {
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx2 => x86::encoder_avx2(enc, x, layout, scratch),
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx512 => x86::encoder_avx512(enc, x, layout, scratch),
    }
}

/// [`encoder`] with the sequences split over `scratch.len()` rayon workers (one scratch each).
pub(crate) fn encoder_par(
    isa: Isa,
    enc: &FastEncoder,
    x: &mut [f32],
    layout: SeqLayout,
    scratch: &mut [FastScratch],
) {
    if scratch.len() <= 1 || layout.num_seq <= 1 {
        if let Some(sc) = scratch.first_mut() {
            encoder(isa, enc, x, layout, sc);
        }
        return;
    }
    if !scratch.iter().all(|sc| check_encoder(enc, x, layout, sc)) {
        return;
    }
    match isa.0 {
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx2 => x86::encoder_par_avx2(enc, x, layout, scratch),
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx512 => x86::encoder_par_avx512(enc, x, layout, scratch),
    }
}

/// The residual-block tail for the tokens of coordinates `k0..k0 + h.len() / (L·C)` (K × L
/// token-major, L = `inp.frames`): `z = mid(y) + cond`, `g = σ(z_gate)·tanh(z_filter)`,
/// `[r | s] = out(g)`, `h = (h + r)/√2`, `skip += s`, and `y = h + next_bias` if asked.
pub(crate) fn block_tail(
    isa: Isa,
    inp: &TailInputs<'_>,
    k0: usize,
    streams: TailStreams<'_>,
    scratch: &mut FastScratch,
) {
    let (frames, c) = (inp.frames, inp.channels);
    let TailStreams { y, h, skip } = &streams;
    let n = h.len();
    let rows = frames * c;
    assert!(
        rows > 0 && n.is_multiple_of(rows) && y.len() == n && skip.len() == n,
        "tail sizes"
    );
    let nk = n / rows;
    let c2 = 2 * c;
    assert!(
        inp.mid.0.in_dim == c
            && inp.mid.0.out_dim == c2
            && inp.out.0.in_dim == c
            && inp.out.0.out_dim == c2
    );
    assert!(inp.mask.len() >= (k0 + nk) * frames && inp.time_tab.len() >= frames * c2);
    assert!(inp.cond_feature.len() >= (k0 + nk) * c2 && inp.cond_mask.len() >= c2);
    assert!(inp.next_bias.is_none_or(|b| b.len() >= c));
    assert!(
        scratch.zt.len() >= frames * c2 && scratch.gt.len() >= frames * c,
        "tail scratch"
    );
    match isa.0 {
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx2 => x86::tail_avx2(inp, k0, streams, scratch),
        #[cfg(target_arch = "x86_64")]
        IsaKind::Avx512 => x86::tail_avx512(inp, k0, streams, scratch),
    }
}
