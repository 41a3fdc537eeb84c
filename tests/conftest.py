"""What the whole suite shares: the data location, the ``data`` marker's skip, and one seeded tiny model
directory per session.

Markers (registered in pyproject.toml): ``data`` (needs the real motion data; skips, naming the missing
file, where it is absent), ``slow`` (a few seconds or more each: training runs, every-kernel cascades,
benchmark smoke runs) and ``bench`` (every test under ``benches/``, given here). The default run selects
all of them; ``pytest -m "not slow"`` is the quick loop while editing.
"""
import hashlib
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("TCD_DATA_DIR", ROOT.parent / "shared" / "data"))
H36M_DIR = DATA / "h36m"


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
    """A seeded random-init ``tiny`` model directory (short, long, model.json), made once per session and
    shared by every module that only reads it. A test that edits model files copies it first; the
    teardown fails the session if any test changed it in place."""
    from training.export import random_init_dir  # needs torch (a dev dependency)

    d = random_init_dir(tmp_path_factory.mktemp("tiny_model") / "m", preset="tiny", seed=3)
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
    import torch
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
