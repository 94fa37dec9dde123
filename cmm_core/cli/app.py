"""``cmm-error-lab app``: start the app in the browser, from wherever the package is
installed (a wheel, ``pip install .``, an editable checkout, ``make run``).

The app's files are the ``cmm_error_lab_app`` package of the wheel (the checkout's
``app.py``, ``serve.py``, ``pages/`` and ``.streamlit/``); its server runs in a child
process, started by ``serve.py`` as ``make run`` always did (the app's modules imported
before the first visitor, its settings passed as flags). The core does not import the
app: it only finds its folder. Standard library only, so ``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import importlib.util
import signal
import subprocess
import sys
from pathlib import Path

__all__ = ["APP_PACKAGE", "DEFAULT_HOST", "DEFAULT_PORT", "add_app_arguments", "app_folder",
           "serve_app", "server_command"]

APP_PACKAGE = "cmm_error_lab_app"
"""The app's package in the wheel."""
DEFAULT_HOST = "127.0.0.1"
"""This computer only: serving the lab's network is a stated choice (``--host``)."""
DEFAULT_PORT = 8501


def add_app_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``app``."""
    p.add_argument("--port", type=int, default=DEFAULT_PORT, metavar="N",
                   help=f"port the app listens on (default {DEFAULT_PORT}); the address "
                        "to open is printed when the server is ready")
    p.add_argument("--host", default=DEFAULT_HOST, metavar="ADDR",
                   help=f"network address to listen on (default {DEFAULT_HOST}: this "
                        "computer only). 0.0.0.0 serves every network interface: anyone "
                        "on the lab's network who has or guesses a session's URL then "
                        "reaches that analysis")
    p.add_argument("--open", action="store_true",
                   help="open the app in this computer's web browser once it is ready")


def app_folder() -> Path:
    """The folder holding ``app.py`` and ``serve.py``: the installed app package, else
    the checkout this package runs from. FileNotFoundError when neither is there."""
    spec = importlib.util.find_spec(APP_PACKAGE)
    places = [Path(p) for p in (spec.submodule_search_locations or [])] if spec else []
    places.append(Path(__file__).resolve().parents[2])  # a checkout run in place
    for place in places:
        if (place / "serve.py").is_file() and (place / "app.py").is_file():
            return place
    raise FileNotFoundError("the app's files (app.py, serve.py) are not installed with "
                            "this package; reinstall it with `pip install cmm-error-lab` "
                            "or run from a checkout.")


def server_command(port: int, host: str, open_browser: bool = False) -> list[str]:
    """The command that serves the app (``python serve.py`` with its options)."""
    if not 0 < port < 65536:
        raise ValueError(f"--port must be from 1 to 65535, found {port}.")
    return [sys.executable, str(app_folder() / "serve.py"), "--server.port", str(port),
            "--server.address", host, "--server.headless", "false" if open_browser else "true"]


def serve_app(args: argparse.Namespace) -> int:
    """Serve the app until interrupted (Ctrl+C); returns the server's exit code."""
    cmd = server_command(args.port, args.host, args.open)
    print(f"CMM error lab: starting on http://{args.host}:{args.port} (Ctrl+C stops it)",
          file=sys.stderr)
    proc = subprocess.Popen(cmd)

    def stopped(signum, _frame):
        raise SystemExit(128 + signum)  # unwinds to the finally below

    # a service manager or a test stops this process with SIGTERM, which the server (a
    # child, not in the terminal's process group then) would not get: it is passed on,
    # so no server outlives the command
    previous = signal.signal(signal.SIGTERM, stopped)
    try:
        return proc.wait()
    except KeyboardInterrupt:  # the server got the same interrupt: let it finish
        try:
            return proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
