"""Shared fixtures: paths from __file__, seeded generators, the thesis dataset."""

import os
import re
import socket
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from streamlit.runtime.memory_media_file_storage import MemoryMediaFileStorage

# The app keeps every analysis in a per-user folder (cmm_core.analysis.sessions): the tests,
# and the app servers they start, keep theirs in a folder of their own, never the user's.
os.environ["CMM_LAB_SESSIONS"] = tempfile.mkdtemp(prefix="cmm-lab-sessions-")

ROOT = Path(__file__).resolve().parents[1]
THESIS = ROOT / "sample_data" / "thesis"


@pytest.fixture(autouse=True, scope="session")
def _apptest_runs_the_frame():
    """AppTest runs the app as the server does (serve.py's ``legacy_pages_off``): every run
    goes through ``app.py``, the frame, and its ``st.navigation``. Each AppTest run resets
    Streamlit's legacy-pages flag, and with a ``pages/`` folder beside ``app.py`` it would
    then run a switched-to page's script alone, without the frame."""
    try:
        from streamlit.runtime.pages_manager import PagesManager
        from streamlit.testing.v1 import app_test
    except ImportError:  # the core's tests run without streamlit too
        yield
        return

    class FramePagesManager(PagesManager):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            PagesManager.uses_pages_directory = False

    app_test.PagesManager = FramePagesManager
    yield
    app_test.PagesManager = PagesManager


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


@pytest.fixture(scope="session")
def rxz4_files(tmp_path_factory):
    """The files of the 80 mm layout with a 3 µrad rxz:4 hidden from a baseline without
    squareness (the rivals sxy and rxz:4): the measure-next command line's case."""
    from scenarios import simulated

    out = tmp_path_factory.mktemp("next")
    simulated("pitch80_3pos", 3, noise_um=0.5,
              kinematic={"spec": "kinematic21,rxz:4", "coefficients": {"rxz[4]": 3.0}}
              ).write(out)
    return out


def svg_figures(at) -> dict:
    """The static SVG figures on the AppTest ``at``'s page (``widgets.svg_figure``: each an
    iframe's document): ``{key: document}``, the key the ``data-figure`` of its ``div``, in
    page order."""
    out = {}
    for f in at.get("iframe"):
        m = re.search(r'<div data-figure="([^"]+)">', f.proto.srcdoc)
        if m:
            out[m.group(1)] = f.proto.srcdoc
    return out


def open_data_tab(at, tab: str, *, instruments: bool = False):
    """Open the Data page's tab ``tab`` (and the instruments expander) in the AppTest ``at``
    and run it: their widgets are drawn only while open (issue 27)."""
    at.session_state["data_tab"] = tab
    if instruments:
        at.session_state["w_instruments_open"] = True
    at.run()
    return at


def uploader(at, label: str):
    """The Data page's file field whose label starts with ``label``, its tab (or the
    instruments expander) opened first when it is not drawn: the upload fields' keys change
    after every load, and a closed tab draws none (issue 27)."""
    def find():
        return [u for u in at.file_uploader if u.label.startswith(label)]

    if not find():
        instruments = not label.startswith(("Measurement", "Setup", "Certificate", "Project"))
        open_data_tab(at, "Project file" if label.startswith("Project") else "Upload CSVs",
                      instruments=instruments)
    return find()[0]


def part_correction(dataset, token: str):
    """A fit of ``dataset`` with ``token`` added to kinematic21, its model saved and read
    back, and the measured points compensated with and without the token's part:
    ``(fit, model, delta_um (n, 3), r_mm (n, 3) readings, p_mm (n, 3) probe offsets)``,
    ``delta_um`` the part's share of the correction (the part: ``model.parts[token]``)."""
    from dataclasses import replace

    from cmm_core.export import compensate, model_from_dict, model_to_dict
    from cmm_core.model import fit

    r = fit(dataset, f"kinematic21,{token}")
    m = model_from_dict(model_to_dict(r))
    pts = dataset.meas[["probe", "mx_mm", "my_mm", "mz_mm"]].rename(
        columns={"mx_mm": "x_mm", "my_mm": "y_mm", "mz_mm": "z_mm"})
    cols = ["ex_um", "ey_um", "ez_um"]
    delta = (compensate(m, pts)[cols].to_numpy()
             - compensate(replace(m, parts={}, cov=m.cov), pts)[cols].to_numpy())
    r_mm = pts[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    p_mm = np.array([m.probes_mm[q] for q in pts["probe"].astype(str)])
    return r, m, delta, r_mm, p_mm


def free_port() -> int:
    """A TCP port nothing listens on now (for an app server a test starts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until_served(proc, url: str, seconds: float = 90.0) -> None:
    """Wait until the Streamlit server ``proc`` answers at ``url`` (its health check);
    RuntimeError with the server's last output when it exits or does not answer."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        if proc.poll() is not None:
            out = proc.stdout.read().decode(errors="replace") if proc.stdout else ""
            raise RuntimeError("the app's server exited: " + out[-3000:])
        try:
            with urllib.request.urlopen(url + "/_stcore/health", timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.3)
    raise RuntimeError(f"the app's server did not answer within {seconds:g} s")


@pytest.fixture
def downloads(monkeypatch):
    """``{file name: bytes}`` of every file the app hands to a download button (AppTest
    keeps a download's bytes in its in-memory media storage; caught on their way in)."""
    seen = {}
    add = MemoryMediaFileStorage.load_and_get_id

    def record(self, path_or_data, mimetype, kind, filename=None):
        seen[filename] = path_or_data
        return add(self, path_or_data, mimetype, kind, filename)

    monkeypatch.setattr(MemoryMediaFileStorage, "load_and_get_id", record)
    return seen
