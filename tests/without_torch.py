"""Run pytest as if PyTorch were not installed:

    python3 tests/without_torch.py [pytest arguments]      # e.g. -q -m "not slow" tests/test_api.py

What it simulates: the environment of a user who installs the package (numpy only at run time) with its test
dependencies (the ``test`` extra) but without torch, and runs its tests. A finder put first on ``sys.meta_path``
makes ``import torch`` and every ``torch.*`` import raise ``ModuleNotFoundError``, the error a missing package
raises, so ``pytest.importorskip("torch")`` skips as it would there; then pytest runs with the given arguments. The
processes some tests start (the ``tcd`` command, a second pytest on tests/test_interrupt.py) do not inherit the
finder; they run the package, which never imports torch.

Why: torch is in the ``reference`` extra (and ``dev``), for the training code (``training/``) and for the tests that
compare the engine with its PyTorch reference; the package's own tests must not need it. In the one environment CI
has (torch installed for the rest of the suite) this checks that they pass without it, on the committed fixtures
(tests/fixtures), and that every test that needs torch skips, saying why (``conftest.import_torch``). CI runs the
suite through it after the main test command (``.ci/run``).
"""

import sys


class _NoTorch:
    """A meta-path finder, first on ``sys.meta_path``: refuses ``torch`` before any other finder sees it."""

    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r} (tests/without_torch.py hides it)", name=name)
        return None


def main(argv: list[str]) -> int:
    if "torch" in sys.modules:  # nothing imports it before this, but say so if it ever does
        raise SystemExit("tests/without_torch.py: torch was imported before it could be hidden")
    sys.meta_path.insert(0, _NoTorch())
    import pytest

    return pytest.main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
