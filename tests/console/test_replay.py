"""The HTML replay: self-contained (images inline, no external reference) and animated in a real browser."""
from __future__ import annotations

import base64
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from console.replay import export_html, keyframes, render_html
from console.store import SessionStore

from session_fixture import make_session, stack_scene


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
    from planning.sim import ShelfSim

    sim = ShelfSim(scene)
    try:
        preview = [sim.remove("b0", record=True).to_json(frames=True)]
    finally:
        sim.close()
    keys = keyframes(scene, ("b0",), preview)
    assert len(keys) > 3 and keys[0]["label"] == "start"
    top0 = max(z for _, z in keys[0]["polys"]["b1"])
    top_end = max(z for _, z in keys[-1]["polys"]["b1"]) if "b1" in keys[-1]["polys"] else -1.0
    assert top0 == pytest.approx(0.4, abs=0.01)
    assert top_end < top0 - 0.1  # b1 fell when b0 was pulled from under it
    static = keyframes(scene, ("b2", "b0"), None)
    assert [sorted(k["polys"]) for k in static] == [["b0", "b1", "b2"], ["b0", "b1"], ["b1"]]


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
