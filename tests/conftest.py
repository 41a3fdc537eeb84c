import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("TCD_DATA_DIR", ROOT.parent / "shared" / "data"))
H36M_DIR = DATA / "h36m"

needs_h36m = pytest.mark.skipif(not (H36M_DIR / "h36m_expmap_50fps.npz").is_file(),
                                reason=f"Human3.6M data not found in {H36M_DIR}")
