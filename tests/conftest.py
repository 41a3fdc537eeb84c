"""What the whole suite shares: the data location, the ``data`` marker's skip, and one seeded tiny model
directory per session.

Markers (registered in pyproject.toml): ``data`` (needs the real motion data; skips, naming the missing
file, where it is absent), ``slow`` (a few seconds or more each: training runs, every-kernel cascades,
benchmark smoke runs) and ``bench`` (every test under ``benches/``, given here). The default run selects
all of them; ``pytest -m "not slow"`` is the quick loop while editing.

Torch: the package needs numpy only, and its tests run without torch (``python3 tests/without_torch.py``
checks that). A module or test that needs torch (the PyTorch reference, the training code) gets it through
:func:`import_torch`, which skips it, saying why, where torch is not installed.
"""

import hashlib
import os
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("TCD_DATA_DIR", ROOT.parent / "shared" / "data"))
H36M_DIR = DATA / "h36m"
FIXTURES = ROOT / "tests" / "fixtures"
TORCH_HINT = "the PyTorch reference and the training stack: pip install '.[reference]' (or '.[dev]')"


def import_torch(what: str):
    """``torch``; where it is not installed, a skip that names ``what`` needs it (e.g. "parity with the PyTorch
    reference"): of the whole module at its top (``torch = import_torch(...)`` before the imports of
    ``training`` modules that import torch), of one test inside it."""
    __tracebackhide__ = True  # the skip is reported at the caller's line
    return pytest.importorskip("torch", reason=f"{what} needs torch ({TORCH_HINT})")


def needs_data(*files: str):
    """Decorator: marks a test ``data`` and skips it when any of ``files`` (relative to the data directory)
    is absent."""
    missing = [str(DATA / f) for f in files if not (DATA / f).exists()]
    skip = pytest.mark.skipif(bool(missing), reason=f"motion data not found: {', '.join(missing)}")
    return lambda test: pytest.mark.data(skip(test))


needs_h36m = needs_data("h36m/h36m_expmap_50fps.npz")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if ROOT / "benches" in Path(item.fspath).parents:
            item.add_marker(pytest.mark.bench)


def _digest(directory: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


@pytest.fixture(scope="session")
def tiny_model_dir(tmp_path_factory):
    """A seeded random-init ``tiny`` model directory (short, long, model.json): a copy of the committed
    ``tests/fixtures/tiny_model`` (what ``training.export.random_init_dir(preset="tiny", seed=3)`` writes;
    tests/fixtures/README.md), so no torch is needed, made once per session and shared by every module that
    only reads it. A test that edits model files copies it first; the teardown fails the session if any test
    changed it in place."""
    d = Path(shutil.copytree(FIXTURES / "tiny_model", tmp_path_factory.mktemp("tiny_model") / "m"))
    before = _digest(d)
    yield d
    assert _digest(d) == before, f"a test changed the shared model directory {d} in place"


@pytest.fixture(scope="session")
def tiny_model(tiny_model_dir):
    """``tcd.load(tiny_model_dir)``: the model is immutable, so one instance serves the session."""
    import tcd

    return tcd.load(tiny_model_dir)


@pytest.fixture(scope="module")
def one_torch_thread():
    """For a module (``pytestmark = pytest.mark.usefixtures("one_torch_thread")``) that runs the PyTorch
    reference beside the engine: PyTorch's intra-op threads thrash on a busy 2-core machine (10-30x
    slower), so it uses one."""
    torch = import_torch("a module that runs the PyTorch reference")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
