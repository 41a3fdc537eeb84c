"""One denoiser forward of tcd against its peers, same weights, same inputs, one run.

    python3 -m pip install ".[dev,peers]"
    python3 benches/peers.py [--preset full] [--lengths 75 55] [--threads 1 2] [--reps 21]
                             [--peers tcd torch ort openvino] [--compile] [--whole-forecast] [--json OUT]

Peers (installed by the ``peers`` extra, never by the package):

* ``tcd``: the Rust engine through the binding, ``Denoiser.forward(..., threads=t)`` (SIMD kernels where the
  CPU has them; one forward split over ``t`` threads);
* ``torch``: PyTorch eager (``training.model``), ``torch.set_num_threads(t)``;
* ``ort``: ONNX Runtime CPU execution provider, ``intra_op_num_threads = t``, all graph optimisations;
* ``openvino``: OpenVINO CPU f32, ``PERFORMANCE_HINT = LATENCY``, ``INFERENCE_NUM_THREADS = t``;
* ``compile`` (with ``--compile``): ``torch.compile`` (inductor) of the eager model.

The model is a seeded random-init denoiser of the paper's size (``--preset full``: 12 layers, 64 channels,
8 heads, K = 66), batch 1, exported once to ONNX per window length L (fixed shapes). Every peer's output is
checked against PyTorch before timing (max abs difference reported). Timing: after 3 warm-up calls each,
``--reps`` rounds in which every peer runs once, in turn (interleaved), and the median per peer.
Ratios are peer / tcd (above 1: tcd is faster).

``--whole-forecast`` also times what a user runs: ``TCD.forecast`` on the same random-init model (short-term
L = 55 and long-term L = 75), 5 samples x DDPM-50 (the paper's 500 forwards) and DDIM-10 x 1 sample, all
cores; the peers' whole-forecast times are *estimated* from their per-forward medians at the most threads
(250 forwards at L = 55 + 250 at L = 75, as ENGINE.md does), and the peak resident memory of a forecast is
measured in a fresh process that imports only ``tcd``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import tcd  # noqa: E402
from machine import cpu_model, cpu_simd_flags  # noqa: E402
from training.export import load_model_file, random_init_dir  # noqa: E402

STEP = 25
ALL_PEERS = ("tcd", "torch", "ort", "openvino")


def inputs(K: int, L: int, obs: int = 50):
    rng = np.random.default_rng(0)
    noisy = rng.normal(size=(1, K, L)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(1, K, L)).astype(np.float32)
    mask = np.zeros((1, K, L), np.float32)
    mask[..., :obs] = 1
    return noisy, observed, mask


def export_onnx(model, arrays, path: Path) -> Path:
    args = tuple(torch.from_numpy(a) for a in arrays) + (torch.tensor([STEP], dtype=torch.long),)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer notes on shape checks: the shapes are fixed per export
        torch.onnx.export(
            model,
            args,
            str(path),
            input_names=["noisy", "observed", "mask", "step"],
            output_names=["eps"],
            opset_version=17,
            dynamo=False,
        )
    return path


def make_peers(names, model, onnx_path: Path, den, arrays, threads: int, compiled=None):
    """name -> zero-argument callable returning the (1, K, L) output as numpy."""
    noisy, observed, mask = arrays
    t_in = [torch.from_numpy(a) for a in arrays] + [torch.tensor([STEP], dtype=torch.long)]
    feeds = {"noisy": noisy, "observed": observed, "mask": mask, "step": np.array([STEP], np.int64)}
    fns = {}
    if "tcd" in names:
        fns["tcd"] = lambda: den.forward(noisy, observed, mask, STEP, threads=threads)
    if "torch" in names:

        def run_torch():
            torch.set_num_threads(threads)
            with torch.no_grad():
                return model(*t_in).numpy()

        fns["torch"] = run_torch
    if compiled is not None:

        def run_compiled():
            torch.set_num_threads(threads)
            with torch.no_grad():
                return compiled(*t_in).numpy()

        fns["torch.compile"] = run_compiled
    if "ort" in names:
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
        so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        sess = ort.InferenceSession(str(onnx_path), so, providers=["CPUExecutionProvider"])
        fns["ort"] = lambda: sess.run(None, feeds)[0]
    if "openvino" in names:
        import openvino as ov

        core = ov.Core()
        compiled_ov = core.compile_model(
            str(onnx_path),
            "CPU",
            {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32"},
        )
        req = compiled_ov.create_infer_request()
        fns["openvino"] = lambda: np.array(req.infer(feeds)[compiled_ov.output(0)])
    return fns


def time_interleaved(fns: dict, reps: int, warmup: int = 3, settle: float = 0.0) -> dict:
    """Median ms per peer; ``settle`` seconds of sleep before each timed call, so that the worker
    threads the previous peer leaves spin-waiting (OpenMP, TBB, rayon) have gone to sleep and do not
    compete with the next peer for the cores."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times = {k: [] for k in fns}
    for _ in range(reps):
        for name, fn in fns.items():
            if settle > 0:
                time.sleep(settle)
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {k: 1000 * statistics.median(v) for k, v in times.items()}


def peak_rss_of_forecast(model_dir: Path, kw: dict) -> float:
    """MiB: the peak resident set (VmHWM) of a fresh process that imports tcd (no torch) and runs one
    forecast. VmHWM, not ru_maxrss: Linux carries ru_maxrss over exec from the (large) forking parent."""
    code = (
        "import numpy as np, tcd\nfrom tcd import SamplerOptions\n"
        f"m = tcd.load({str(model_dir)!r})\n"
        "obs = np.random.default_rng(0).normal(scale=0.3, size=(50, m.num_joints, 3)).astype(np.float32)\n"
        f"m.forecast(obs, **{kw!r})\n"
        "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]\n"
        "print(int(hwm.split()[1]) / 1024)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def whole_forecast(model_dir: Path, reps: int) -> dict:
    m = tcd.load(model_dir)
    obs = np.random.default_rng(0).normal(scale=0.3, size=(50, m.num_joints, 3)).astype(np.float32)
    runs = {
        "ddpm50_x5": dict(num_samples=5, seed=0),
        "ddim10_x1": dict(
            num_samples=1, sampler=m.sampler_options("forecast", num_inference_steps=10, sampler="ddim"), seed=0
        ),
    }
    out = {}
    for name, kw in runs.items():
        m.forecast(obs, **kw)  # warm-up
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            m.forecast(obs, **kw)
            ts.append(time.perf_counter() - t0)
        out[name] = {
            "seconds": statistics.median(ts),
            "reps": reps,
            "peak_rss_mib": peak_rss_of_forecast(model_dir, kw),
        }
        print(
            f"whole forecast {name}: tcd {out[name]['seconds']:.2f} s (median of {reps}), "
            f"peak RSS {out[name]['peak_rss_mib']:.0f} MiB"
        )
    return out


def versions() -> dict:
    v = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "tcd": tcd.__version__,
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "tcd_kernel": os.environ.get("TCD_KERNEL", "auto"),
        # what auto resolves to here, and the CPU's SIMD flags (a VM may hide AVX-512)
        "tcd_supported_kernels": tcd.engine.supported_kernels(),
        "cpu_simd_flags": cpu_simd_flags(),
    }
    for mod in ("onnxruntime", "openvino"):
        try:
            v[mod] = __import__(mod).__version__
        except ImportError:
            v[mod] = None
    return v


NAMES = {
    "tcd": "tcd",
    "torch": "PyTorch eager",
    "ort": "ONNX Runtime",
    "openvino": "OpenVINO",
    "compile": "torch.compile",
}


def markdown(result: dict) -> str:
    """The README's tables of a result (``--table-from`` prints them from a saved ``--json``)."""
    rows = result["rows"]
    peers = [p for p in NAMES if any(p in r["ms"] for r in rows)]
    head = "| ms per forward | " + " | ".join(f"L = {r['L']}, {r['threads']} thr." for r in rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    for p in peers:
        cells = []
        for r in rows:
            ms = r["ms"].get(p)
            ratio = r.get("peer_over_tcd", {}).get(p)
            cells.append("" if ms is None else f"{ms:.1f}" + ("" if ratio is None else f" ({ratio:.2f}×)"))
        lines.append(f"| {NAMES[p]} | " + " | ".join(cells) + " |")
    wf = result.get("whole_forecast")
    if wf:
        d = wf["ddpm50_x5"]
        lines += [
            "",
            "| whole forecast | tcd (measured) | "
            + " | ".join(f"{NAMES[k]} (estimated)" for k in sorted(d.get("peers_estimated_seconds", {})))
            + " |",
            "|---" * (2 + len(d.get("peers_estimated_seconds", {}))) + "|",
            "| DDPM-50 × 5 samples, both stages (s) | "
            + f"{d['seconds']:.1f} | "
            + " | ".join(f"{v:.1f}" for _, v in sorted(d.get("peers_estimated_seconds", {}).items()))
            + " |",
        ]
        if "ddim10_x1" in wf:
            lines.append(
                f"| DDIM-10 × 1 sample (s) | {wf['ddim10_x1']['seconds']:.2f} |"
                + " |" * len(d.get("peers_estimated_seconds", {}))
            )
        lines.append("")
        lines.append(
            "Peak resident memory of a forecast (fresh process): "
            + ", ".join(f"{k} {v['peak_rss_mib']:.0f} MiB" for k, v in wf.items() if "peak_rss_mib" in v)
            + "."
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="full", choices=["full", "tiny"])
    ap.add_argument("--lengths", type=int, nargs="+", default=[75, 55])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--reps", type=int, default=21)
    ap.add_argument(
        "--settle",
        type=float,
        default=0.3,
        help="seconds of sleep before each timed call (spinning worker threads of the previous "
        "peer go idle; without it the peer timed next is slowed, up to ~20 %% measured)",
    )
    ap.add_argument("--peers", nargs="+", default=list(ALL_PEERS), choices=ALL_PEERS)
    ap.add_argument("--compile", action="store_true", help="also time torch.compile (inductor; slow to compile)")
    ap.add_argument("--whole-forecast", action="store_true", help="also time TCD.forecast (see the docstring)")
    ap.add_argument("--forecast-reps", type=int, default=3)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--table-from",
        default=None,
        metavar="JSON",
        help="print the markdown tables of a saved --json result and exit (runs nothing)",
    )
    args = ap.parse_args(argv)
    if args.table_from:
        print(markdown(json.loads(Path(args.table_from).read_text())))
        return 0
    for p in ("ort", "openvino"):
        if p in args.peers:
            try:
                __import__({"ort": "onnxruntime", "openvino": "openvino"}[p])
            except ImportError:
                ap.error(f'peer {p!r} is not installed: python3 -m pip install ".[peers]" (or leave it out of --peers)')
    tmp = Path(tempfile.mkdtemp(prefix="tcd_peers_"))
    d = random_init_dir(tmp / "model", preset=args.preset, seed=0)
    rows = []
    for L in args.lengths:
        path = d / ("long.safetensors" if L > 55 else "short.safetensors")
        model, _, cfg = load_model_file(path)
        model.eval()
        K = cfg["model"]["num_features"]
        arrays = inputs(K, L)
        onnx_path = export_onnx(model, arrays, tmp / f"denoiser_L{L}.onnx")
        compiled = torch.compile(model) if args.compile else None
        den = tcd.engine.Denoiser.load(path)
        for threads in args.threads:
            fns = make_peers(args.peers, model, onnx_path, den, arrays, threads, compiled)
            ref = fns["torch"]() if "torch" in fns else None
            diffs = {}
            if ref is not None:
                for name, fn in fns.items():
                    diffs[name] = float(np.abs(fn() - ref).max())
                    np.testing.assert_allclose(fn(), ref, rtol=1e-3, atol=1e-4, err_msg=f"{name} disagrees with torch")
            med = time_interleaved(fns, args.reps, settle=args.settle)
            row = {"L": L, "K": K, "threads": threads, "reps": args.reps, "ms": med, "max_abs_diff_vs_torch": diffs}
            if "tcd" in med:
                row["peer_over_tcd"] = {k: v / med["tcd"] for k, v in med.items() if k != "tcd"}
            rows.append(row)
            print(
                f"L={L} threads={threads}: "
                + ", ".join(f"{k} {v:.1f} ms" for k, v in med.items())
                + (
                    ""
                    if "tcd" not in med
                    else "  | peer/tcd " + ", ".join(f"{k} {v:.2f}" for k, v in row["peer_over_tcd"].items())
                )
            )
    result = {"preset": args.preset, "step": STEP, "settle_s": args.settle, "versions": versions(), "rows": rows}
    if args.whole_forecast:
        tmax = max(args.threads)
        wf = whole_forecast(d, args.forecast_reps)
        est = {}
        for name in {k for r in rows for k in r["ms"]} - {"tcd"}:
            per = {r["L"]: r["ms"][name] for r in rows if r["threads"] == tmax and name in r["ms"]}
            if 55 in per and 75 in per:
                est[name] = 250 * (per[55] + per[75]) / 1000
        wf["ddpm50_x5"]["peers_estimated_seconds"] = est
        for k, v in sorted(est.items()):
            print(f"whole forecast ddpm50_x5: {k} ~{v:.1f} s (estimated, {tmax} threads)")
        result["whole_forecast"] = wf
    print(markdown(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
