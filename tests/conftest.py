"""Shared fixtures: paths from __file__, seeded generators, the thesis dataset."""

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
THESIS = ROOT / "sample_data" / "thesis"


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)


@pytest.fixture(scope="session")
def thesis():
    from cmm_core.io import thesis_dataset

    return thesis_dataset()


@pytest.fixture(scope="session")
def thesis_clean(thesis):
    """The thesis data and the exclusions of its flagged blunders."""
    from cmm_core.diagnosis import detect_outliers

    return thesis, detect_outliers(thesis).exclusions
