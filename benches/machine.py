"""What a benchmark records of the machine it ran on (the CPU varies between sessions: compare only results
of one machine). Shared by benches/peers.py, benches/prior_speed.py and benches/train_speed.py."""

from __future__ import annotations

import platform
from pathlib import Path

# The flags that decide tcd's kernel path and torch's bf16 / AMX paths (a VM may hide some of them).
SIMD_FLAGS = {
    "avx",
    "avx2",
    "fma",
    "avx512f",
    "avx512bw",
    "avx512vl",
    "avx512_bf16",
    "avx512_fp16",
    "amx_tile",
    "amx_bf16",
}


def _cpuinfo() -> list[str]:
    try:
        return Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return []


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what the platform module says."""
    for line in _cpuinfo():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def cpu_simd_flags() -> list[str]:
    """The CPU's flags among SIMD_FLAGS, sorted (empty where /proc/cpuinfo cannot be read)."""
    flags = next((line.split(":", 1)[1].split() for line in _cpuinfo() if line.startswith("flags")), [])
    return sorted(f for f in flags if f in SIMD_FLAGS)
