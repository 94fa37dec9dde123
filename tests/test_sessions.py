"""An analysis survives a reload (issue 27): the store of saved sessions
(``cmm_core.analysis.sessions``) and the app's restore through it, in AppTest (the browser's
F5 and second tab are in tests/test_browser.py)."""

import os
import stat
import time
from pathlib import Path

import pytest
from conftest import svg_figures
from streamlit.testing.v1 import AppTest

from cmm_core import analysis as A
from cmm_core.analysis import (
    SessionConflict,
    SessionStore,
    default_session_folder,
    new_session_id,
    sessions,
    text_digest,
    valid_session_id,
)

ROOT = Path(__file__).resolve().parents[1]
APP = str(ROOT / "app.py")


@pytest.fixture
def store(tmp_path):
    return SessionStore(tmp_path / "sessions")


def test_ids_are_random_and_only_their_own_form_becomes_a_file(store):
    ids = {new_session_id() for _ in range(100)}
    assert len(ids) == 100 and all(valid_session_id(i) for i in ids)
    for bad in ("../../etc/passwd", "A" * 32, "0" * 31, "0" * 33, "", None, 12,
                "0" * 32 + "/x", "0" * 16 + ".." + "0" * 14):
        assert not valid_session_id(bad)
        assert store.load(bad) is None
    with pytest.raises(ValueError, match="expected 32 hex digits"):
        store.save("../evil", "{}")
    assert not store.folder.exists()  # nothing written for a refused id


def test_save_load_forget_and_no_temporary_file_left(store):
    sid = new_session_id()
    assert store.load(sid) is None
    p = store.save(sid, '{"a": 1}')
    store.save(sid, '{"a": 2}')  # atomic replace
    got = store.load(sid)
    assert got.text == '{"a": 2}' and got.path == p and got.session_id == sid
    assert abs(got.saved - time.time()) < 60
    assert [q.name for q in store.folder.iterdir()] == [f"{sid}.json"]
    store.forget(sid)
    assert store.load(sid) is None
    store.forget(sid)  # twice: nothing to do


def test_prune_removes_only_old_analyses(store):
    old, new = new_session_id(), new_session_id()
    store.save(old, "{}")
    store.save(new, "{}")
    foreign = store.folder / "notes.json"  # not a session file: never touched
    foreign.write_text("{}")
    month = time.time() - 31 * 86400
    os.utime(store.path(old), (month, month))
    os.utime(foreign, (month, month))
    assert store.prune() == 1
    assert store.load(old) is None and store.load(new) is not None and foreign.exists()
    assert SessionStore(store.folder / "missing").prune() == 0


def _app(sid=None):
    at = AppTest.from_file(APP, default_timeout=120)
    if sid is not None:
        at.query_params["session"] = sid
    at.run()
    assert not at.exception, at.exception
    return at


def _store():
    return SessionStore(Path(os.environ["CMM_LAB_SESSIONS"]))


def test_a_changed_analysis_is_restored_by_a_new_session_with_its_id():
    at = _app()
    sid = at.session_state["session_id"]
    assert at.query_params["session"] == sid
    assert _store().load(sid) is None  # the untouched default analysis is not written
    at.switch_page("pages/kinematic.py").run()
    at.text_input(key="w_spec").set_value("kinematic21,plate_sag").run()
    at.session_state["exclusions"] = [["BP112", "2", 7]]
    at.session_state["history"] = [{"spec": "kinematic21", "change": "baseline"},
                                   {"spec": "kinematic21,plate_sag", "change": "+ plate_sag"}]
    at.run()
    assert _store().load(sid) is not None
    again = _app(sid)  # F5: a new browser session on the same URL
    s = again.session_state
    assert s["session_id"] == sid and s["spec"] == "kinematic21,plate_sag"
    assert s["exclusions"] == [["BP112", "2", 7]]
    assert [h["change"] for h in s["history"]] == ["baseline", "+ plate_sag"]
    note = " ".join(i.value for i in again.info)
    assert "Restored from" in note and sid in note
    # the data's own file names, not "from the saved session" alone (issue 41)
    assert "Data: thesis tables 6.1-6.6 (BP111.csv, " in note, note
    assert s["ds_origin"]["setup_source"].startswith("setup.json, from the saved session")
    fresh = _app()  # another browser: its own analysis
    assert fresh.session_state["session_id"] != sid
    assert fresh.session_state["spec"] == "kinematic21"
    assert not any("Restored" in i.value for i in fresh.info)
    # start afresh: the saved file goes, a new id, the thesis defaults
    again.button(key="start_afresh").click().run()
    assert not again.exception
    assert again.session_state["session_id"] != sid and again.session_state["spec"] == "kinematic21"
    assert _store().load(sid) is None
    assert not any("Restored" in i.value for i in again.info)


def test_a_damaged_saved_file_is_said_and_kept_and_a_new_analysis_starts():
    sid = new_session_id()
    path = _store().save(sid, '{"format": "not a project"')
    at = _app(sid)
    msg = " ".join(e.value for e in at.error)
    assert "could not be restored" in msg and sid in msg
    assert str(path.parent) not in msg  # no server path on screen (issue 38)
    assert at.session_state["session_id"] != sid and path.exists()
    assert at.session_state["spec"] == "kinematic21"


def test_an_unknown_id_in_a_link_is_never_adopted_and_the_user_is_told():
    """Session fixation (issue 38): a well-formed id with nothing saved under it starts a
    new analysis with the server's own id, so whoever sent the link cannot later open the
    analysis its user makes; the page says a new analysis was started."""
    planted = new_session_id()
    at = _app(planted)
    sid = at.session_state["session_id"]
    assert sid != planted and valid_session_id(sid) and at.query_params["session"] == sid
    assert any("new analysis was started" in i.value for i in at.info)
    at.switch_page("pages/kinematic.py").run()
    at.text_input(key="w_spec").set_value("kinematic21,plate_sag").run()
    assert _store().load(planted) is None and _store().load(sid) is not None


def test_a_link_with_a_malformed_id_never_reads_a_file_and_gets_a_new_id():
    at = _app("../../etc/passwd")
    sid = at.session_state["session_id"]
    assert valid_session_id(sid) and at.query_params["session"] == sid
    assert not at.error


@pytest.mark.parametrize("where", ["instrument", "measurement", "interim_check"])
def test_an_uploaded_project_naming_a_server_path_is_refused_in_one_line(tmp_path, where):
    """Issue 38: a project file uploaded to the app may not name its files by path (an
    absolute path or ``../``): the restore is refused in one line naming the field, the
    server's file is never read (its text appears nowhere), the session keeps its data."""
    import json

    from conftest import uploader

    from cmm_core import analysis as A

    secret = tmp_path / "secret.csv"
    secret.write_text("TOP SECRET first line\n1,2,3\n")
    doc = json.loads(A.record_to_project_json(A.read_record(
        ROOT / "sample_data" / "thesis" / "analysis.json")))
    rest = doc["extra"]["analysis"]
    if where == "instrument":
        rest["instruments"] = [{"kind": "laser", "name": "x.csv", "path": str(secret)}]
    elif where == "measurement":
        rest["mappings"] = [{"index": 0, "name": "v.csv", "path": "../" * 8 + str(secret),
                             "mapping": {"x": "X", "y": "Y", "z": "Z", "label": "L"}}]
    else:
        rest["interim_check"] = {"model": {"name": "m.json", "path": str(secret)}}
    at = _app()
    at.switch_page("pages/data.py").run()
    uploader(at, "Project file").set_value(
        ("p.json", json.dumps(doc).encode(), "application/json"))
    at.run()
    at.button(key="restore_project").click().run()
    assert not at.exception
    shown = " ".join([e.value for e in at.error] + [i.value for i in at.info]
                     + [m.value for m in at.markdown] + list(svg_figures(at).values()))
    assert "TOP SECRET" not in shown
    (err,) = [e.value for e in at.error]
    assert "\n" not in err and ("by a path" in err or "p.json" in err), err
    assert at.session_state["sources"].name == "thesis tables 6.1-6.6"


@pytest.mark.parametrize(("platform", "environ", "expected"), [
    ("win32", {"LOCALAPPDATA": r"C:\Users\ana\AppData\Local"},
     Path(r"C:\Users\ana\AppData\Local") / "cmm-error-lab" / "sessions"),
    ("win32", {}, Path("/home/ana") / "AppData" / "Local" / "cmm-error-lab" / "sessions"),
    ("darwin", {}, Path("/home/ana") / "Library" / "Application Support" / "cmm-error-lab"
     / "sessions"),
    ("linux", {"XDG_STATE_HOME": "/srv/state"}, Path("/srv/state/cmm-error-lab/sessions")),
    ("linux", {}, Path("/home/ana/.local/state/cmm-error-lab/sessions")),
    ("darwin", {"CMM_LAB_SESSIONS": "/data/s"}, Path("/data/s")),
])
def test_the_sessions_folder_is_where_each_system_keeps_a_users_state(platform, environ,
                                                                      expected):
    assert default_session_folder(platform, environ, Path("/home/ana")) == expected


@pytest.mark.skipif(os.name != "posix", reason="file modes are POSIX")
def test_saved_analyses_are_readable_by_their_owner_only(tmp_path):
    folder = tmp_path / "sessions"
    folder.mkdir(mode=0o755)
    os.chmod(folder, 0o755)  # made before the rule, or under a wide umask
    store = SessionStore(folder)
    p = store.save(new_session_id(), "{}")
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE(p.stat().st_mode) == 0o600


@pytest.mark.skipif(os.name != "posix", reason="links and FIFOs as POSIX makes them")
def test_a_link_a_fifo_or_an_oversized_file_named_like_a_session_is_not_read(store, tmp_path,
                                                                          monkeypatch):
    secret = tmp_path / "secret.json"
    secret.write_text('{"not": "yours"}')
    store.folder.mkdir(mode=0o700)
    linked, fifo, big = new_session_id(), new_session_id(), new_session_id()
    (store.folder / f"{linked}.json").symlink_to(secret)
    os.mkfifo(store.folder / f"{fifo}.json")  # a read would block the reload
    (store.folder / f"{big}.json").write_text("{}" + " " * 100)
    monkeypatch.setattr(sessions, "MAX_SESSION_BYTES", 50)
    assert store.load(linked) is None and store.load(fifo) is None and store.load(big) is None
    # a save replaces the planted link, it never writes through it
    store.save(linked, '{"mine": 1}')
    assert secret.read_text() == '{"not": "yours"}'
    assert not (store.folder / f"{linked}.json").is_symlink()
    assert store.load(linked).text == '{"mine": 1}'


def test_a_save_over_another_writers_version_is_refused_and_nothing_is_written(store):
    sid = new_session_id()
    store.save(sid, '{"v": 1}', expected=None)  # a new analysis: no file yet
    mine = text_digest('{"v": 1}')
    store.save(sid, '{"v": 2}', expected=mine)  # the tab's own last version: written
    with pytest.raises(SessionConflict, match="another tab"):
        store.save(sid, '{"v": 3}', expected=mine)  # another tab wrote v2 meanwhile
    assert store.load(sid).text == '{"v": 2}'
    with pytest.raises(SessionConflict):
        store.save(sid, '{"v": 4}', expected=None)  # "no file yet", but there is one
    # a lock left by a server killed mid-save is taken over once it is stale
    lock = store.folder / f"{sid}.lock"
    lock.write_text("")
    old = time.time() - 2 * sessions.STALE_LOCK_S
    os.utime(lock, (old, old))
    store.save(sid, '{"v": 5}', expected=store.load(sid).digest)
    assert store.load(sid).text == '{"v": 5}' and not lock.exists()


def test_two_tabs_on_one_analysis_never_lose_a_change_silently():
    """Tab A and tab B restore the same analysis; A saves a change; B's later change is
    not written over A's: B is told to reload, and the file keeps A's version."""
    first = _app()
    sid = first.session_state["session_id"]
    first.switch_page("pages/kinematic.py").run()
    first.text_input(key="w_spec").set_value("kinematic21,plate_sag").run()
    a, b = _app(sid), _app(sid)
    for tab, spec in ((a, "kinematic21,backlash"), (b, "kinematic21,drift")):
        tab.switch_page("pages/kinematic.py").run()
        tab.text_input(key="w_spec").set_value(spec).run()
        assert not tab.exception
    saved = A.record_from_project(_store().load(sid).text, "saved")
    assert saved.spec == "kinematic21,backlash"
    warned = " ".join(w.value for w in b.sidebar.warning)
    assert "changed in another tab" in warned and "reload" in warned
    assert "changed in another tab" not in " ".join(w.value for w in a.sidebar.warning)
