"""serve.py (``make run``): the app's modules imported before the server starts."""

import subprocess
import sys

from conftest import ROOT

sys.path.insert(0, str(ROOT))
import serve  # noqa: E402


def test_app_imports_are_the_scripts_top_level_imports():
    names = serve.app_imports()
    # app.py's own, a page's helper, a core wing a page imports, a third-party module
    for name in ("streamlit", "pages.session", "pages.frame", "cmm_core.analysis", "numpy"):
        assert name in names
    assert names == sorted(set(names))


def test_preload_imports_every_module_and_nothing_runs_streamlit():
    """In a fresh interpreter: the app's helpers and the core are imported, no page script
    is executed (none is imported), and no warning about a missing runtime is printed."""
    code = ("import sys, serve; done = serve.preload(); "
            "print(all(m in sys.modules for m in done), len(done), "
            "'pages.data' in sys.modules, 'cmm_core' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    ok, n, page_run, core = out.stdout.split()
    assert ok == "True" and int(n) >= 10 and page_run == "False" and core == "True"
    assert "No runtime found" not in out.stderr
