"""Start the app's server (``make run``) with the app's modules imported first.

``streamlit run app.py`` imports numpy, scipy, pandas, plotly and ``cmm_core`` inside the
first script run of the first session: the first person to open the app after a server
start waited about 1.8 s longer than everyone after (issue 27). Here every module the
app's scripts import at their top is imported before the server starts, so the server
prints its URL that much later and the first page is as quick as any later one (the
server-start preload of gunicorn's ``--preload``, for the same reason).

It also carries the app's settings: Streamlit reads ``.streamlit/config.toml`` from the
folder it is started in, which is the checkout for ``make run`` but anywhere for an
installed ``cmm-error-lab app``; here the file beside this script is passed as command-line
flags, so the app looks and behaves the same wherever it was started. The server listens on
127.0.0.1 unless an address is given.

Arguments after the script are those of ``streamlit run`` (they win over the file)::

    python serve.py --server.port 8501 --server.address 127.0.0.1
"""

from __future__ import annotations

import ast
import importlib
import logging
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent
APP = ROOT / "app.py"
CONFIG = ROOT / ".streamlit" / "config.toml"
LOOPBACK = "127.0.0.1"
"""The default address: this computer only. Another address is a stated choice."""
OPEN_WARNING = ("serving {address}: anyone who can reach this computer on port {port} and "
                "has (or guesses) a session's URL reaches that analysis.")


def config_flags(path: Path = CONFIG) -> list[str]:
    """The settings of ``path`` (Streamlit's ``config.toml``) as ``streamlit run`` flags,
    ``--section.option value``; booleans as ``true``/``false``."""
    flags: list[str] = []
    with open(path, "rb") as f:
        for section, options in tomllib.load(f).items():
            for name, value in options.items():
                text = str(value).lower() if isinstance(value, bool) else str(value)
                flags += [f"--{section}.{name}", text]
    return flags


def server_args(args: list[str], config: Path = CONFIG) -> list[str]:
    """``args`` (``streamlit run`` options) completed by :func:`config_flags` for every
    option they do not set, and by ``--server.address 127.0.0.1`` when they set none."""
    given = {a.split("=", 1)[0] for a in args if a.startswith("--")}
    defaults = config_flags(config) if config.is_file() else []
    if "--server.address" not in given:
        defaults += ["--server.address", LOOPBACK]
    kept = [x for flag, value in zip(defaults[::2], defaults[1::2], strict=True)
            if flag not in given for x in (flag, value)]
    return [*kept, *args]


def option(args: list[str], name: str, default: str) -> str:
    """The value of ``--name`` in ``args`` (``--name value`` or ``--name=value``); the
    last one counts, as in ``streamlit run``."""
    value = default
    for i, a in enumerate(args):
        if a == name and i + 1 < len(args):
            value = args[i + 1]
        elif a.startswith(name + "="):
            value = a.split("=", 1)[1]
    return value


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

    args = server_args(sys.argv[1:] if argv is None else argv)
    address = option(args, "--server.address", LOOPBACK)
    if address not in (LOOPBACK, "localhost", "::1"):
        print("cmm-error-lab: " + OPEN_WARNING.format(
            address=address, port=option(args, "--server.port", "8501")), file=sys.stderr)
    preload()
    legacy_pages_off()
    sys.argv = ["streamlit", "run", str(APP), *args]
    streamlit_main(prog_name="streamlit")


if __name__ == "__main__":
    main()
