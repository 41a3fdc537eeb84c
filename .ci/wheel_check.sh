#!/usr/bin/env bash
# The release path, as a user without a Rust toolchain meets it: build the sdist and the abi3 manylinux wheel
# (scripts/build_wheels.sh), install the wheel into a fresh virtual environment with no cargo/rustc on the
# PATH, and run `tcd demo` and a smoke test from outside the source tree (so nothing imports the checkout).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build_wheels.sh
root=$(pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m venv "$work/venv"
nort_path="$work/venv/bin:/usr/local/bin:/usr/bin:/bin"
if PATH="$nort_path" command -v cargo >/dev/null || PATH="$nort_path" command -v rustc >/dev/null; then
    echo "wheel check: a Rust toolchain is still on the PATH" >&2; exit 1
fi
cd "$work"
start=$(date +%s.%N)
PATH="$nort_path" python -m pip install -q "$root"/dist/*.whl
echo "wheel check: installed in $(python3 -c "print(round($(date +%s.%N) - $start, 1))") s"
PATH="$nort_path" tcd --version
PATH="$nort_path" tcd demo -o "$work/demo.npz" --steps 5 --quiet | tail -n 1
PATH="$nort_path" python - <<'PY'
import numpy as np, tcd
assert "/venv/" in tcd.__file__, tcd.__file__             # the installed wheel, not the checkout
obs = np.load(tcd.__file__.replace("__init__.py", "data/demo_walking.npz"))["poses"][:50]
ddim5 = tcd.SamplerOptions(sampler="ddim", num_inference_steps=5)
f = tcd.load().forecast(obs, num_samples=2, seed=0, sampler=ddim5)
assert f.mean.shape == (25, 22, 3) and np.isfinite(f.mean).all()
# the release build's kernels agree: the portable path equals the fastest this CPU has (read at load time)
import os
os.environ["TCD_KERNEL"] = "portable"
p = tcd.load().forecast(obs, num_samples=2, seed=0, sampler=ddim5)
assert np.allclose(p.mean, f.mean, rtol=1e-4, atol=1e-5), np.abs(p.mean - f.mean).max()
print("wheel check: smoke test passed,", tcd.__version__, tcd.engine.supported_kernels())
PY
# the HumanEva-I model, where this tree bundles it (python/tcd/weights_humaneva/); without it, tcd.load("humaneva")
# says it is not bundled
if [ -f "$root/python/tcd/weights_humaneva/short.safetensors" ]; then
    PATH="$nort_path" python - <<'PY'
import numpy as np, tcd
m = tcd.load("humaneva")
assert "/venv/" in str(m.path), m.path
ddim2 = tcd.SamplerOptions(sampler="ddim", num_inference_steps=2)
f = m.forecast(np.zeros((15, 14, 3), np.float32), num_samples=50, seed=0, sampler=ddim2)
assert f.samples.shape == (50, 60, 14, 3) and np.isfinite(f.samples).all()
print("wheel check: the bundled HumanEva-I model forecasts 50 samples")
PY
    PATH="$nort_path" tcd demo --model humaneva -o "$work/demo_humaneva.npz" --steps 2 --quiet | tail -n 1
else
    PATH="$nort_path" python -c "
import tcd
try:
    tcd.load('humaneva')
except tcd.ModelNotBundledError as e:
    print('wheel check: no HumanEva-I model bundled:', str(e)[:60], '...')
else:
    raise SystemExit('tcd.load(\"humaneva\") loaded a model the tree does not bundle')
"
fi
# the Setting-A model, where this tree bundles it (python/tcd/weights_h36m_stochastic/: a generator directory)
if [ -f "$root/python/tcd/weights_h36m_stochastic/generator.safetensors" ]; then
    PATH="$nort_path" python - <<'PY'
import numpy as np, tcd
m = tcd.load("h36m-stochastic")
assert "/venv/" in str(m.path), m.path
f = m.forecast(np.zeros((25, 16, 3), np.float32), num_samples=50, seed=0)
assert f.samples.shape == (50, 100, 16, 3) and np.isfinite(f.samples).all()
print("wheel check: the bundled Setting-A model forecasts 50 samples of 100 frames")
PY
    PATH="$nort_path" tcd demo --model h36m-stochastic -o "$work/demo_setting_a.npz" --quiet | tail -n 1
fi
# the oldest CPython the abi3 wheel claims, where this machine has it (on the PATH or under pyenv)
py39=""
for candidate in python3.9 "$HOME"/.pyenv/versions/3.9*/bin/python3.9; do
    if "$candidate" -c "" 2>/dev/null; then py39=$candidate; break; fi
done
if [ -n "$py39" ]; then
    "$py39" -m venv "$work/venv39"
    PATH="$work/venv39/bin:/usr/local/bin:/usr/bin:/bin" python -m pip install -q "$root"/dist/*.whl
    PATH="$work/venv39/bin:/usr/local/bin:/usr/bin:/bin" tcd demo -o "$work/demo39.npz" --steps 2 --quiet | tail -n 1
    echo "wheel check: Python 3.9 runs the wheel"
fi
# the sdist builds too (Rust sources and weights inside): a wheel from it, with the toolchain back on the PATH
cd "$root"
python3 -m pip wheel -q --no-deps dist/*.tar.gz -w "$work/from_sdist"
python3 - "$work"/from_sdist/*.whl <<'PY'
import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
assert "tcd/weights/short.safetensors" in names and "tcd/weights/prior.safetensors" in names and "tcd/data/demo_walking.npz" in names, names
assert "tcd/data/demo_walking_humaneva.npz" in names, names
import os
bundled = sorted(f for f in os.listdir("python/tcd/weights_humaneva")) if os.path.isdir("python/tcd/weights_humaneva") else []
if "short.safetensors" in bundled:
    missing = [f for f in bundled if not f.startswith(".") and "tcd/weights_humaneva/" + f not in names]
    assert not missing, missing
    print("wheel check: ... and the HumanEva-I model,", ", ".join(bundled))
setting_a = sorted(os.listdir("python/tcd/weights_h36m_stochastic")) if os.path.isdir("python/tcd/weights_h36m_stochastic") else []
if "generator.safetensors" in setting_a:
    missing = [f for f in setting_a if "tcd/weights_h36m_stochastic/" + f not in names]
    missing += [] if "tcd/data/demo_walking_setting_a.npz" in names else ["demo_walking_setting_a.npz"]
    assert not missing, missing
    print("wheel check: ... and the Setting-A model,", ", ".join(setting_a))
print("wheel check: the sdist builds a wheel with the weights and the demo clip")
PY
