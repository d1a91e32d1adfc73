"""The viser layer as a hostile peer would meet it: outside text arrives as literal text (never
markup) in every view and in the HTML replay; the passphrase field is cleared after every use; two
supervisors and five viewers at once on one real viser server. Real workflow, SQLite, TCP robot."""
from __future__ import annotations

import html
import re
import threading
import time
from html.parser import HTMLParser

import pytest

from safety_kit import HonestPeer, fault, judge_session  # noqa: F401
from test_workflow import PASS, CodeShelfSource, small_scene

MARKUP = ('<iframe src="javascript:alert(1)"></iframe><script>alert(2)</script>'
          '![x](http://evil.example/pixel.png) [click](http://evil.example/) **bold** | cell |')


def literal(md: str, text: str) -> bool:
    """`text` shows as is (entities decoded) and no markup character of it reaches the markdown raw."""
    shown = html.unescape(md).replace("\u2060", "")          # the word joiners that stop autolinks
    return text in shown and not re.search(r"<(iframe|script)|\]\(http|!\[|https?:", md)


@pytest.fixture
def app(tmp_path):
    from types import SimpleNamespace

    import viser

    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    peer = HonestPeer(script=lambda conn, step: "refuse" if step == 1 else "ok")
    store = SessionStore(tmp_path / "app.sqlite")
    wf = Workflow(CodeShelfSource(small_scene()), store,
                  lambda truth, seed: open_robot(peer.url, truth=truth, seed=seed), PASS, samples=2)
    a = ConsoleApp(wf, port=0)
    # seven views on the real server, as seven browsers would get (server-wide GUI handles); each
    # draws its 3D shelf on a scene of its own, as a browser's client does: on one shared scene each
    # view's nodes replaced the others' ("Cannot assign to 'position' on a removed BoxHandle")
    scenes = [viser.ViserServer(host="127.0.0.1", port=0, verbose=False) for _ in range(7)]
    views = [ClientView(a, SimpleNamespace(gui=a.server.gui, scene=sc.scene, atomic=sc.atomic)) for sc in scenes]
    for i, v in enumerate(views):
        v.client_key = f"browser-{i}"
        a.views[1000 + i] = v
    yield a, wf, views, peer
    a.stop()
    for sc in scenes:
        sc.stop()
    store.close()
    peer.close()


def settle(wf, views, timeout=10.0):
    """Wait until every view drew the latest state."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = wf.state.version
        time.sleep(0.2)
        if wf.state.version == v:
            return
    raise AssertionError("the state kept changing")


def test_outside_text_is_literal_in_every_view_and_supervisors_race(app, monkeypatch):
    a, wf, views, peer = app
    # the supervisors' names and a perception note are hostile; the robot refuses step 2
    peer.message = MARKUP                                      # the robot's refusal text is hostile too
    st = wf.capture()
    wf._set(warnings=(MARKUP,))
    wf.plan("clear", wait=True)
    sups = views[:2]
    for v in sups:
        v.approve_plan.value = "physics"
    # the supervisors type once their views show the plan (what is typed before is cleared then)
    end = time.monotonic() + 30
    while not all(v.supervisor.reviewed == ("physics", wf.state.plans["physics"].hash) for v in sups):
        assert time.monotonic() < end, "the supervisor views never showed the plan"
        time.sleep(0.05)
    for v, name in zip(sups, ("<img src=x onerror=alert(5)>", "[ann](http://evil.example/)")):
        v.who.value = name
        v.passphrase.value = PASS
    fault(2)
    go = threading.Barrier(2)
    ts = [threading.Thread(target=lambda v=v: (go.wait(), v._approve(None))) for v in sups]
    [t.start() for t in ts]
    [t.join(30) for t in ts]
    wf.wait_robot(30)
    settle(wf, views)
    rec = wf.store.load_session(st.session_id)
    approved = [d for d in rec.decisions if d["decision"] == "approve"]
    assert len(approved) == 1                                  # exactly one approval stored, and it ran
    assert [e["kind"] for e in rec.robot_events if e["kind"] == "start"] == ["start"]
    assert all(v.passphrase.value == "" for v in sups)         # the field never keeps it
    assert wf.state.robot == "failed"
    for v in views:                                            # five viewers and both supervisors
        assert literal(v.status.content, MARKUP)
        assert literal(v.decisions_md.content, approved[0]["who"])
        assert literal(v.robot_md.content, MARKUP)


def test_robot_error_markup_is_literal_text(app):
    a, wf, views, peer = app
    from shelfpick.console.web.app import robot_markdown, status_markdown
    from shelfpick.console.robot.drivers import RobotEvent, RobotOutcome
    from shelfpick.console.workflow.machine import State

    st = State(robot="failed", robot_events=(RobotEvent("error", 1, "b<1>", {"message": MARKUP}),),
               outcome=RobotOutcome(("b0",), False, MARKUP, ()), error=f"robot: {MARKUP}", message=MARKUP,
               source="files:<x>", target="[t](http://e/)")
    fault()
    assert literal(robot_markdown(st), MARKUP) and literal(status_markdown(st), MARKUP)
    assert "b<1>" in html.unescape(robot_markdown(st)) and "<1>" not in robot_markdown(st)


def test_passphrase_is_cleared_even_when_refused(app):
    a, wf, views, peer = app
    v = views[0]
    wf.capture()
    wf.plan("clear", wait=True)
    v.passphrase.value = "wrong wrong wrong"
    v.accept_risk.value = True                 # else the refusal is the unticked box's, before the passphrase
    v._approve(None)
    assert v.passphrase.value == ""
    v.passphrase.value = PASS
    v.reason.value = ""
    v._reject(None)                                            # refused (no reason): still cleared
    assert v.passphrase.value == ""


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.text: list[str] = []
        self.img_src: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "img":
            self.img_src.append(dict(attrs).get("src") or "")

    def handle_data(self, data):
        self.text.append(data)


def test_replay_shows_outside_text_literally(tmp_path):
    """Supervisor names, reasons, robot error text and scene-check notes stored in a session come
    back in the HTML replay as text: no iframe, no extra script, no image from outside."""
    from shelfpick.console.web.replay import render_html
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.planning.plan import Plan, StepPrediction

    from test_store import tiny_capture, tiny_scene

    store = SessionStore(tmp_path / "r.sqlite")
    sid = store.new_session(MARKUP, tiny_capture(), tiny_scene(), None, None, {"warnings": [MARKUP]})
    plan = Plan("extract", "b0", "physics", ("b2", "b0"), (StepPrediction("b2"), StepPrediction("b0")), False,
                {}, 0, {"scene_check": {"stands_as_seen": False, "problems": [{"box": "b2", "what": MARKUP}]}})
    h = store.add_plan(sid, plan)
    store.add_decision(sid, h, "approve", MARKUP, MARKUP)
    store.add_robot_event(sid, h, "error", 0, "b2", {"message": MARKUP})
    store.set_outcome(sid, {"plan": h, "sequence": ["b2", "b0"], "ok": False, "error": MARKUP, "completed": [],
                            "steps": [{"step": 0, "box": "b2", "status": "error", "detail": {"message": MARKUP}}]})
    page = render_html(store.load_session(sid))
    p = _Tags()
    p.feed(page)
    fault()
    assert "iframe" not in p.tags and p.tags.count("script") == 2   # the plan's JSON data + our code
    assert all(src.startswith("data:image/png") for src in p.img_src)  # only the capture images
    text = "".join(p.text)
    assert text.count(MARKUP) >= 5 and "The shelf does not stand as seen" in text
    from shelfpick.console.web.app import record_view
    view = record_view(store.load_session(sid))
    assert literal(view.summary_md, MARKUP) and literal(view.plans_md, MARKUP)
    store.close()


def test_box_ids_from_a_scene_file_do_not_name_scene_nodes(app):
    """Ids are outside text: 'a/label' or '..' must not land on another box's node."""
    from shelfpick.console.web.scene_view import draw_boxes
    from shelfpick.perception.scene import Box, Scene, Shelf

    a, wf, views, peer = app
    scene = Scene(Shelf(), (Box("a", (0.2, 0.2, 0.2), (-0.3, 0.1, 0.1)),
                            Box("a/label", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),
                            Box("..", (0.2, 0.2, 0.2), (0.3, 0.1, 0.1))))
    fault()
    nodes = draw_boxes(a.server.scene, scene)
    names = {n.box.name for n in nodes.values()} | {n.label.name for n in nodes.values()}
    assert set(nodes) == {"a", "a/label", ".."} and len(names) == 6


# ------------------------------------------------- issue 30: the passphrase's source, allowed origins
def console_args(tmp_path, *extra):
    from shelfpick.console.cli import build_parser

    return build_parser().parse_args(["console", "--port", "0", "--no-capture", "--db", str(tmp_path / "c.db"),
                                      *extra])


def refused(args) -> str:
    """build() must refuse in one line (ShelfpickError) before anything is opened."""
    from shelfpick.console import cmd_console
    from shelfpick.perception.errors import ShelfpickError

    try:
        parts = cmd_console.build(args)
    except ShelfpickError as exc:
        return str(exc)
    parts[0].stop()
    parts[2].close()
    pytest.fail("the console started")


@pytest.mark.parametrize("pw", ["aaaaaaaaaaaa", "abcdefabcdef", "qwertyuiopas", "Password1234!", "abcdefghijkl"])
@pytest.mark.parametrize("how", ["env", "file"])
def test_a_trivial_passphrase_beyond_localhost_refuses_to_start(pw, how, tmp_path, monkeypatch):
    from shelfpick.console.cmd_console import ENV_PASSPHRASE

    monkeypatch.delenv(ENV_PASSPHRASE, raising=False)
    extra = ["--host", "0.0.0.0"]
    if how == "env":
        monkeypatch.setenv(ENV_PASSPHRASE, pw)
    else:
        (tmp_path / "pw").write_text(pw + "\n")
        (tmp_path / "pw").chmod(0o600)
        extra += ["--supervisor-passphrase-file", str(tmp_path / "pw")]
    fault()
    msg = refused(console_args(tmp_path, *extra))
    assert msg.startswith(ENV_PASSPHRASE if how == "env" else f"--supervisor-passphrase-file {tmp_path / 'pw'}")
    assert "refused when listening on 0.0.0.0" in msg and "\n" not in msg
    assert not (tmp_path / "c.db").exists()


def test_the_passphrase_comes_from_a_file_or_the_environment_not_only_argv(tmp_path, monkeypatch, caplog):
    import os

    from shelfpick.console import cmd_console

    monkeypatch.delenv(cmd_console.ENV_PASSPHRASE, raising=False)
    pw = tmp_path / "pw"
    pw.write_text("tulip 7 cobalt ferry\nsecond line ignored\n")
    pw.chmod(0o640)
    with caplog.at_level("WARNING"):
        app, wf, store, _, given, _ = cmd_console.build(console_args(tmp_path, "--host", "0.0.0.0",
                                                                     "--supervisor-passphrase-file", str(pw)))
    try:
        assert given and wf._passphrase == "tulip 7 cobalt ferry"
        assert "other users may read it (mode 640)" in caplog.text
    finally:
        app.stop()
        store.close()
    monkeypatch.setenv(cmd_console.ENV_PASSPHRASE, "heron 4 basalt quill")
    app, wf, store, _, given, _ = cmd_console.build(console_args(tmp_path, "--host", "0.0.0.0"))
    try:
        assert given and wf._passphrase == "heron 4 basalt quill"
    finally:
        app.stop()
        store.close()
    fault(4)
    assert "give one of them" in refused(console_args(tmp_path, "--supervisor-passphrase", "x" * 20,
                                                      "--supervisor-passphrase-file", str(pw)))
    (tmp_path / "empty").write_text("\n")
    assert "the first line is empty" in refused(console_args(tmp_path, "--supervisor-passphrase-file",
                                                             str(tmp_path / "empty")))
    (tmp_path / "big").write_text("y" * 5000)
    assert "at most 4096" in refused(console_args(tmp_path, "--supervisor-passphrase-file", str(tmp_path / "big")))
    os.mkfifo(tmp_path / "fifo")                                     # must not block the start
    assert "not a regular file" in refused(console_args(tmp_path, "--supervisor-passphrase-file",
                                                        str(tmp_path / "fifo")))


def test_allowed_origins_come_from_the_command_line_or_the_cell_file(tmp_path):
    from websockets.exceptions import InvalidStatus

    from shelfpick.console import cmd_console
    from shelfpick.console.cell import CellError
    from test_origin import websocket

    fault(2)
    assert refused(console_args(tmp_path, "--allow-origin", "https://proxy.example/app")).startswith(
        "--allow-origin 'https://proxy.example/app': an origin is scheme, host and port only")
    cell = tmp_path / "cell.toml"
    cell.write_text('[safety]\nallow_origins = ["https://Cell.example:443"]\n')
    app, wf, store, *_ = cmd_console.build(console_args(tmp_path, "--cell", str(cell)))
    try:
        with websocket(app, "https://cell.example") as ws:
            assert ws.recv(timeout=10)
        with pytest.raises(InvalidStatus):
            websocket(app, "https://proxy.example")
    finally:
        app.stop()
        store.close()
    cell.write_text('[safety]\nallow_origins = ["https://cell.example/x"]\n')
    with pytest.raises(CellError, match=r"cell.toml: safety.allow_origins: 'https://cell.example/x': an origin"):
        cmd_console.build(console_args(tmp_path, "--cell", str(cell)))
