"""serve.py (``make run``): the app's modules imported before the server starts."""

import subprocess
import sys
import tomllib

from conftest import ROOT

if str(ROOT) not in sys.path:  # pytest's rootdir insertion already has it
    sys.path.insert(0, str(ROOT))
import serve  # noqa: E402


def test_app_imports_are_the_scripts_top_level_imports():
    names = serve.app_imports()
    # app.py's own, a page's helper, a core wing a page imports, a third-party module
    for name in ("streamlit", "pages.ui.session", "pages.ui.widgets", "cmm_core.analysis", "numpy"):
        assert name in names
    assert names == sorted(set(names))


def test_preload_imports_every_module_and_nothing_runs_streamlit():
    """In a fresh interpreter: the app's helpers and the core are imported, no page's
    body runs (a Streamlit call outside a session would warn of a missing
    ScriptRunContext), and no warning about a missing runtime is printed."""
    code = ("import sys, serve; done = serve.preload(); "
            "print(all(m in sys.modules for m in done), len(done), "
            "'pages.data' in sys.modules, 'cmm_core' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    ok, n, page_run, core = out.stdout.split()
    assert ok == "True" and int(n) >= 10 and page_run == "False" and core == "True"
    assert "No runtime found" not in out.stderr
    assert "ScriptRunContext" not in out.stderr and "not imported in advance" not in out.stderr


def test_a_module_that_fails_to_import_is_one_line_and_the_rest_is_imported(tmp_path):
    """A module the scripts import that raises on import does not stop the server: one
    line names it, the other modules are imported (the page shows the error later, as
    ``streamlit run`` would)."""
    bad = tmp_path / "broken_helper.py"
    bad.write_text("raise RuntimeError('a helper that cannot start')\n")
    code = ("import sys, serve; sys.path.insert(0, sys.argv[1]); "
            "serve.app_imports = lambda: ['broken_helper', 'numpy']; "
            "print(serve.preload())")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['numpy']"
    (line,) = [x for x in out.stderr.splitlines() if "broken_helper" in x]
    assert "RuntimeError: a helper that cannot start" in line


def test_the_config_file_becomes_flags_and_the_server_listens_on_this_computer_only():
    """Started outside the checkout, Streamlit would not find ``.streamlit/config.toml``:
    every setting of it is passed as a flag, and the address is 127.0.0.1 unless given."""
    with open(serve.CONFIG, "rb") as f:
        settings = tomllib.load(f)
    args = serve.server_args([])
    pairs = dict(zip(args[::2], args[1::2], strict=True))
    for section, options in settings.items():
        for name, value in options.items():
            expected = str(value).lower() if isinstance(value, bool) else str(value)
            assert pairs[f"--{section}.{name}"] == expected
    assert pairs["--server.address"] == "127.0.0.1"


def test_given_options_win_over_the_file_and_the_default_address():
    args = serve.server_args(["--server.port", "8765", "--server.address=0.0.0.0",
                              "--theme.base", "dark"])
    assert args.count("--theme.base") == 1 and "--server.address" not in args
    assert serve.option(args, "--server.address", "x") == "0.0.0.0"
    assert serve.option(args, "--server.port", "8501") == "8765"
    assert serve.option(args, "--theme.base", "light") == "dark"
