#!/usr/bin/env bash
# Builds the release artifacts into dist/: the sdist (Rust sources, Python package, bundled weights) and one
# abi3 wheel for CPython >= 3.9 on x86-64 Linux, tagged manylinux2014 (glibc 2.17), by maturin with zig as
# the linker (the ziglang package from PyPI: no manylinux container needed). `auditwheel show` prints the
# wheel's platform check, and the wheel's size and contents are listed.
#
#   bash scripts/build_wheels.sh            # dist/tcd_forecast-<version>.tar.gz and ...-cp39-abi3-manylinux*.whl
#
# The kernels are chosen at run time (portable, AVX2, AVX-512): nothing here targets the build machine's CPU.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install -q "maturin>=1.5,<2" "ziglang>=0.11" "auditwheel>=6"
rm -rf dist
python3 -m maturin sdist -o dist
python3 -m maturin build --release --zig --compatibility manylinux2014 -o dist
wheel=$(ls dist/*.whl)
python3 -m auditwheel show "$wheel"
python3 - "$wheel" <<'PY'
import os, sys, zipfile
path = sys.argv[1]
names = zipfile.ZipFile(path).namelist()
print(f"{os.path.basename(path)}: {os.path.getsize(path) / 2**20:.2f} MiB, {len(names)} files")
outside = [n for n in names if not (n.startswith("tcd/") or ".dist-info/" in n)]
if outside:
    sys.exit(f"files outside the package in the wheel: {outside}")
PY
