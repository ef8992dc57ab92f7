"""Shared fixtures. Everything runs off-screen and silent."""
import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")
# single-threaded BLAS before numpy loads: the tests' matrices are small, and threaded BLAS on the
# shared 2-core machine (xdist workers side by side) made them up to 7x slower
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from identify import LinearModel, load_profile  # noqa: E402


@pytest.fixture(scope="session")
def s61_profile():
    return load_profile("s61_hover_8state")


@pytest.fixture(scope="session")
def s61(s61_profile):
    return LinearModel(s61_profile)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
