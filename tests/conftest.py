"""Shared fixtures: paths from __file__, seeded generators, the thesis dataset."""

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

# The app keeps every analysis in a per-user folder (cmm_core.analysis.sessions): the tests,
# and the app servers they start, keep theirs in a folder of their own, never the user's.
os.environ["CMM_LAB_SESSIONS"] = tempfile.mkdtemp(prefix="cmm-lab-sessions-")

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
