"""Golden outputs: the SHA-256 of ``forecast``, ``repair`` and ``tcd repair`` outputs for fixed seeds on a
fixed model directory, per kernel path (issue 16: the redesign must not change a single bit).

``tests/fixtures/golden_model`` is a copy of the reduced bundled weights as they were when the checksums
were recorded, so that new bundled weights do not move them. The checksums are in
``tests/fixtures/golden_sha256.json``, one table per kernel path (the kernel paths round differently, so
each has its own). A kernel path this CPU supports but the file has no table for (AVX-512 on a machine
that never recorded one) is skipped with the command that records it:

    TCD_KERNEL=avx512 python3 tests/test_golden.py --record

A table is recorded once and then must hold on every CPU that runs its path. The avx2 table was re-recorded
once, on 2026-11-25 (issue 27): the AVX2 path had computed reciprocals with ``_mm256_rcp_ps``, whose
estimate differs between Intel and AMD (the table recorded on AMD failed on a Sapphire Rapids Xeon); it
now divides exactly (``crates/tcd-core/src/kernels/x86/simd.rs``). The portable and avx512 tables are
unchanged.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from tcd import SamplerOptions

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
MODEL_DIR = FIXTURES / "golden_model"
CHECKSUMS = FIXTURES / "golden_sha256.json"


def sha(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes()).hexdigest()


def observation() -> np.ndarray:
    """The demo clip's first 50 frames with a seeded occlusion (NaN): 12 % of joint-frames and frames 20-24."""
    import tcd

    clip = np.load(Path(tcd.__file__).parent / "data" / "demo_walking.npz")["poses"][:50].astype(np.float32)
    rng = np.random.default_rng(1234)
    hidden = rng.random(clip.shape[:2]) < 0.12
    hidden[20:25] = True
    obs = clip.copy()
    obs[hidden] = np.nan
    return obs


def outputs(tmp: Path) -> dict[str, str]:
    """The checksummed outputs on the kernel path ``$TCD_KERNEL`` selects (read when a model file loads)."""
    import tcd
    from tcd._cli import main as cli

    model = tcd.load(MODEL_DIR)
    obs = observation()
    out = {"kernel": model.short.kernel}
    f = model.forecast(obs, num_samples=2, seed=0, sampler=SamplerOptions(num_inference_steps=10))
    out.update(
        {
            "forecast_ddpm10_mean": sha(f.mean),
            "forecast_ddpm10_samples": sha(f.samples),
            "forecast_ddpm10_repaired": sha(f.repaired),
        }
    )
    f = model.forecast(
        obs * 1000.0, num_samples=1, seed=3, sampler=SamplerOptions(sampler="ddim", num_inference_steps=5), units="mm"
    )
    out["forecast_ddim5_mm_samples"] = sha(f.samples)
    f = model.forecast(obs, num_samples=1, seed=4, sampler=SamplerOptions(sampler="dpmpp2m", num_inference_steps=5))
    out["forecast_dpmpp2m5_samples"] = sha(f.samples)
    out["repair_ddpm10"] = sha(
        model.repair(obs, num_samples=2, seed=5, sampler=SamplerOptions(num_inference_steps=10)).poses
    )
    seq = np.concatenate([obs, observation()[::-1]])  # 100 frames: two windows and more
    (tmp / "in").mkdir(parents=True, exist_ok=True)
    np.savez(tmp / "in" / "take.npz", poses=seq)
    assert (
        cli(
            [
                "repair",
                str(tmp / "in"),
                "-o",
                str(tmp / "out"),
                "--model",
                str(MODEL_DIR),
                "--steps",
                "10",
                "--samples",
                "2",
                "--quiet",
            ]
        )
        == 0
    )
    with np.load(tmp / "out" / "take.npz") as z:
        out["tcd_repair_cli_poses"] = sha(z["poses"])
    return out


@pytest.mark.slow
def test_golden_outputs_per_kernel(tmp_path, monkeypatch):
    import tcd

    recorded = json.loads(CHECKSUMS.read_text())
    checked = 0
    for kernel in tcd.engine.supported_kernels():
        if kernel not in recorded:
            continue
        monkeypatch.setenv("TCD_KERNEL", kernel)
        got = outputs(tmp_path / kernel)
        assert got == recorded[kernel], f"kernel {kernel}: outputs changed"
        checked += 1
    missing = sorted(set(tcd.engine.supported_kernels()) - set(recorded))
    assert checked >= 1, f"no recorded kernel path among {tcd.engine.supported_kernels()}"
    if missing:
        pytest.skip(
            f"no golden checksums recorded for {missing}: TCD_KERNEL=<kernel> python3 tests/test_golden.py --record"
        )


def test_golden_model_is_the_fixture_copy():
    """The fixture directory is intact (its SHA256SUMS is the bundled file of the recording)."""
    sums = dict(reversed(line.split()) for line in (MODEL_DIR / "SHA256SUMS").read_text().splitlines())
    for name, digest in sums.items():
        assert hashlib.sha256((MODEL_DIR / name).read_bytes()).hexdigest() == digest, name


if __name__ == "__main__" and sys.argv[1:] == ["--record"]:
    import tempfile

    table = json.loads(CHECKSUMS.read_text()) if CHECKSUMS.is_file() else {}
    with tempfile.TemporaryDirectory() as d:
        got = outputs(Path(d))
    kernel = got["kernel"]
    if os.environ.get("TCD_KERNEL") not in (None, kernel):
        sys.exit(f"TCD_KERNEL={os.environ['TCD_KERNEL']} but the model loaded {kernel}")
    table[kernel] = got
    CHECKSUMS.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    print(f"recorded {kernel} in {CHECKSUMS}")
