"""Start the app's server (``make run``) with the app's modules imported first.

``streamlit run app.py`` imports numpy, scipy, pandas, plotly and ``cmm_core`` inside the
first script run of the first session: the first person to open the app after a server
start waited about 1.8 s longer than everyone after (issue 27). Here every module the
app's scripts import at their top is imported before the server starts, so the server
prints its URL that much later and the first page is as quick as any later one (the
server-start preload of gunicorn's ``--preload``, for the same reason).

Arguments after the script are those of ``streamlit run``::

    python serve.py --server.port 8501 --server.headless true
"""

from __future__ import annotations

import ast
import importlib
import logging
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
APP = ROOT / "app.py"


def app_imports() -> list[str]:
    """The modules imported at the top level of ``app.py`` and of every script in
    ``pages/`` (``from pages import frame`` names ``pages.frame``), sorted."""
    names: set[str] = set()
    for path in [APP, *sorted((ROOT / "pages").glob("*.py"))]:
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module)
                names.update(f"{node.module}.{a.name}" for a in node.names)
    return sorted(names)


def preload() -> list[str]:
    """Import :func:`app_imports`; return those that are modules. A name that is not a
    module (``from cmm_core.analysis import fit_kwargs`` also names
    ``cmm_core.analysis.fit_kwargs``) is skipped; a module that fails to import is said in
    one line and left to the session, where the page shows the error as ``streamlit run``
    would (the server starts all the same)."""
    # the app's caches are created when first called, inside the server's runtime; the
    # decorators only check their parameters here and would warn that no runtime exists
    importlib.import_module("streamlit.runtime.caching")  # its loggers, levels of their own
    quiet = [logging.getLogger(n) for n in list(logging.root.manager.loggerDict)
             if n.startswith("streamlit.runtime.caching")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.ERROR)
    sys.path.insert(0, str(ROOT))
    done = []
    try:
        for name in app_imports():
            try:
                importlib.import_module(name)
            except ModuleNotFoundError as exc:
                if exc.name is not None and not name.startswith(exc.name):
                    print(f"serve.py: {name} not imported in advance: {exc}", file=sys.stderr)
                continue
            except Exception as exc:  # noqa: BLE001 - the page will show it
                print(f"serve.py: {name} not imported in advance: {type(exc).__name__}: "
                      f"{exc}", file=sys.stderr)
                continue
            done.append(name)
    finally:
        sys.path.remove(str(ROOT))
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
    return done


def legacy_pages_off() -> None:
    """Turn off Streamlit's legacy multipage list before the server answers. Until the first
    ``st.navigation`` of a server, Streamlit runs a URL such as ``/kinematic`` as the script
    ``pages/kinematic.py`` alone, without ``app.py`` (its frame: state, sidebar,
    navigation); ``st.navigation`` turns the list off for the server's life, and so does
    this, so every first request runs ``app.py`` and its navigation opens the page."""
    from streamlit.runtime.pages_manager import PagesManager

    PagesManager.uses_pages_directory = False


def main(argv: list[str] | None = None) -> None:
    from streamlit.web.cli import main as streamlit_main

    preload()
    legacy_pages_off()
    sys.argv = ["streamlit", "run", str(APP), *(sys.argv[1:] if argv is None else argv)]
    streamlit_main(prog_name="streamlit")


if __name__ == "__main__":
    main()
