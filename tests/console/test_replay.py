"""The HTML replay: self-contained (images inline, no external reference) and animated in a real browser."""
from __future__ import annotations

import base64
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from shelfpick.console.web.replay import export_html, keyframes, render_html
from shelfpick.console.store.sessions import SessionStore

from session_fixture import make_session, replaying, stack_scene


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> tuple[Path, int, dict]:
    db = tmp_path_factory.mktemp("replay") / "data" / "shelfpick.db"
    sid, info = make_session(db)
    return db, sid, info


def test_replay_html_is_self_contained_and_holds_the_session(stored, tmp_path: Path) -> None:
    db, sid, info = stored
    rec = SessionStore(db).load_session(sid)
    out = export_html(rec, tmp_path / "r" / "replay.html")
    page = out.read_text(encoding="utf-8")
    assert not re.search(r"https?://", page), "no external URL may appear"
    assert not re.search(r"""(?:src|href)\s*=\s*["'](?!data:|#)""", page), "every src/href is inline"
    assert "<link" not in page and "@import" not in page
    # the captured RGB is inline and decodes to the very pixels that were stored
    uris = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(uris) == 4  # rgb, overlay, depth, masks
    first = cv2.imdecode(np.frombuffer(base64.b64decode(uris[0]), np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(cv2.cvtColor(first, cv2.COLOR_BGR2RGB), info["rgb"])
    for text in ("physics plan", "heuristic plan", info["physics"], info["heuristic"], "b1 would fall",
                 "supervisor-ana", "approved", "success", "Predicted outcome", "box b1: depth unknown"):
        assert text in page, text
    assert page.count('id="anim') >= 2 and page.count("<polygon") == 6  # 3 boxes x 2 plans


def test_keyframes_follow_the_recorded_collapse() -> None:
    scene = stack_scene()
    from shelfpick.planning.sim import ShelfSim

    sim = ShelfSim(scene)
    try:
        preview = [sim.remove("b0", record=True).to_json(frames=True)]
    finally:
        sim.close()
    keys = keyframes(scene, ("b0",), preview)
    assert len(keys) > 3 and keys[0].label == "start"
    top0 = max(z for _, z in keys[0].polys["b1"])
    top_end = max(z for _, z in keys[-1].polys["b1"]) if "b1" in keys[-1].polys else -1.0
    assert top0 == pytest.approx(0.4, abs=0.01)
    assert top_end < top0 - 0.1  # b1 fell when b0 was pulled from under it
    static = keyframes(scene, ("b2", "b0"), None)
    assert [sorted(k.polys) for k in static] == [["b0", "b1", "b2"], ["b0", "b1"], ["b1"]]


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Debian chromium not installed")
def test_replay_opens_and_animates_in_a_browser_without_network(stored, tmp_path: Path) -> None:
    playwright = pytest.importorskip("playwright.sync_api")
    db, sid, _ = stored
    out = export_html(SessionStore(db).load_session(sid), tmp_path / "replay.html")
    requests: list[str] = []
    errors: list[str] = []
    with playwright.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=[
            "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        try:
            page = browser.new_page()
            page.on("request", lambda r: requests.append(r.url))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(out.as_uri())
            assert page.locator("img").count() == 4
            assert page.evaluate("Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)")
            label = page.locator("#anim0-label")
            assert label.inner_text().startswith("1/")
            poly = page.locator('#anim0-svg polygon[data-box="b1"]')
            start = poly.get_attribute("points")
            page.locator("#anim0-scrub").fill(page.locator("#anim0-scrub").get_attribute("max"))
            assert label.inner_text() != "" and not label.inner_text().startswith("1/")
            assert poly.get_attribute("points") != start  # b1 fell in the recorded preview
            page.locator("#anim0-play").click()  # restarts from the beginning and plays
            page.wait_for_timeout(400)
            assert page.locator("#anim0-play").inner_text() in ("Pause", "Play")
        finally:
            browser.close()
    assert errors == []
    assert all(u.startswith(("file:", "data:")) for u in requests), requests


def looked_session(db: Path) -> tuple[int, str]:
    """The fixture session plus two looks after its physics plan's steps: the first as predicted,
    the second with b2 6 cm left of where the plan put it (observed ids renumbered)."""
    from shelfpick.console.workflow.verify import compare
    from shelfpick.perception.scene import Box

    sid, info = make_session(db)
    scene = stack_scene().without(["b1"])
    seen = scene.with_boxes([Box("o0", b.size, b.position) if b.id == "b0" else
                             Box("o2", b.size, (b.position[0] - 0.06,) + tuple(b.position[1:])) for b in scene.boxes])
    ok = compare(scene, scene, 0, "b1")
    off = compare(scene.without(["b0"]), seen.without(["o0"]), 1, "b0")
    assert ok.within and not off.within and off.ids("moved") == ("b2",)
    with SessionStore(db) as store:
        store.add_verification(sid, info["physics"], "r1", ok.to_json(), scene, scene)
        store.add_verification(sid, info["physics"], "r1", off.to_json(), scene.without(["b0"]),
                               seen.without(["o0"]))
    return sid, info["physics"]


def test_replay_html_shows_predicted_outlines_over_observed_boxes_per_step(tmp_path: Path) -> None:
    db = tmp_path / "looks.db"
    sid, h = looked_session(db)
    page = render_html(SessionStore(db, readonly=True).load_session(sid))
    assert "Looks after each step: predicted vs observed" in page
    cards = re.findall(r'<div class="card" data-look="(\d)">(.*?)</div>', page, re.S)
    assert [c[0] for c in cards] == ["0", "1"]
    first, second = cards[0][1], cards[1][1]
    assert "shelf as predicted" in first and "moved: b2 6.0 cm" in second
    # step 1: b0 and b2 filled, both outlined where predicted; step 2: o2 filled in red, b2 outlined thick
    assert re.findall(r'data-observed="(\w+)"', first) == ["b0", "b2"]
    assert re.findall(r'data-predicted="(\w+)"', first) == ["b0", "b2"]
    obs = re.search(r'<polygon data-observed="o2" points="([^"]+)"[^>]*stroke="#e01e1e"', second)
    pred = re.search(r'<polygon data-predicted="b2" points="([^"]+)"[^>]*stroke-width="0.012"', second)
    assert obs and pred
    xs = lambda pts: [float(p.split(",")[0]) for p in pts.split()]   # noqa: E731
    assert min(xs(pred.group(1))) - min(xs(obs.group(1))) == pytest.approx(0.06, abs=1e-3)


def test_console_replay_draws_a_look_with_predicted_outlines(tmp_path: Path) -> None:
    db = tmp_path / "looks.db"
    sid, _ = looked_session(db)
    store = SessionStore(db)
    try:
        with replaying(store, sid) as view:
            labels = view.look_pick.options[1:]
            assert len(labels) == 2 and labels[1].startswith("step 2 (b0")
            assert "Looks after each step" in view.replay_md.content
            view._show_look(labels[1])
            assert set(view.nodes) == {"o2"} and view.nodes["o2"].risk.visible  # observed, differs: red
            assert len(view.look_nodes) == 1  # b2's predicted pose
            assert tuple(view.look_nodes[0].position) == pytest.approx((0.3, 0.12, 0.1))
            assert "moved" in view.look_md.content
            assert view.drawing.caption_node.text == (f"Replayed session: the shelf seen after {labels[1]}; "
                                                      "outlines: as predicted")
            view._show_look("—")
            assert set(view.nodes) == {"b0", "b1", "b2"} and view.look_nodes == []
    finally:
        store.close()


def test_a_replay_opens_its_preview_at_the_first_frame_even_for_the_plan_already_shown(stored) -> None:
    """The preview keeps its place for the same plan (it gained worlds); a replay is another shelf:
    replaying a session whose preview was played to its end (or the live plan, the same one) drew
    the end, every box pulled, as if the stored shelf were empty."""
    db, sid, _ = stored
    store = SessionStore(db, readonly=True)
    try:
        with replaying(store, sid) as view:
            view.preview.prev_plan.value = "heuristic"          # the plan with a recorded preview
            view.preview.load(force=True)
            last = int(view.preview.slider.max)
            assert last > 0
            view.preview.slider.value = last
            view.preview.show_frame(last)
            view._replay(None)                                  # the same session again
            assert int(view.preview.slider.value) == 0
            view.preview.slider.value = last
            view._live(None)                                    # back to live: no plan there, frame 0
            assert int(view.preview.slider.value) == 0
    finally:
        store.close()


def test_the_3d_view_says_whether_it_draws_the_shelf_or_a_predicted_preview_frame(stored) -> None:
    """One 3D view serves every tab: a preview played to its end (boxes pulled or fallen) looked
    like the shelf to a supervisor on the Supervisor tab. A caption above the shelf says which."""
    db, sid, _ = stored
    store = SessionStore(db, readonly=True)
    try:
        with replaying(store, sid) as view:
            drawing = view.drawing
            assert drawing.caption == f"Replayed session {sid}: the shelf as captured"
            assert drawing.caption_node is not None and drawing.caption_node.text == drawing.caption
            view.preview.prev_plan.value = "heuristic"
            view.preview.load(force=True)
            last = int(view.preview.slider.max)
            view.preview.slider.value = last
            view.preview.show_frame(last)
            fr = view.preview.frames[last]
            nsteps = max(k.step for k in view.preview.frames) + 1
            assert drawing.caption_node.text.startswith(      # the replayed session's, not the live plan
                f"Replayed session {sid}: preview of the heuristic plan, step {nsteps}/{nsteps}")
            assert drawing.caption_node.text.endswith("(predicted, not the shelf as seen)")
            assert fr.world and fr.world in drawing.caption_node.text
            view.preview.prev_plan.value = "physics"            # no recorded preview: the shelf again
            view.preview.load(force=True)
            assert not view.preview.frames
            assert drawing.caption_node.text == f"Replayed session {sid}: the shelf as captured"
    finally:
        store.close()


def test_a_preview_caption_names_what_collapsed_as_plain_text() -> None:
    from shelfpick.console.web.panels import preview_caption
    from shelfpick.console.web.scene_view import Keyframe

    fr = Keyframe(1, "b*2", 0.4, {}, ("<b>x</b>",), "collapses in 3 worlds of 20: shown in world 2")
    cap = preview_caption("physics", fr, 3)
    assert cap == ("Preview of the physics plan, step 2/3, collapses in 3 worlds of 20: shown in world 2; "
                   "collapsed: <b>x</b> (predicted, not the shelf as seen)")
