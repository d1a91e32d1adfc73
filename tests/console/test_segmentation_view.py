"""The Segmentation image shows the faces a plan set aside as unexplained matter, as the 3D view
does (issue 31 item 2): live on a real viser view, in a replay from real SQLite, in the export.
The label images come from a real `perceive` of a real render."""
from __future__ import annotations

import numpy as np
import pytest

HATCH = (40, 40, 40)           # perception.overlay.draw_unexplained's hatch lines


@pytest.fixture(scope="module")
def perceived():
    """A rendered stack perceived by the console's default segmenter: (capture, Perception)."""
    from session_fixture import stack_scene

    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.render import render
    from shelfpick.perception.segment import load_segmenter

    cap = render(stack_scene(), seed=3)
    p = perceive(cap, load_segmenter(None, "auto"))
    assert len(p.scene.boxes) == 3 and all(b.mask_label for b in p.scene.boxes)
    return cap, p


def aside_plan(box: str, other: str):
    from shelfpick.planning.plan import Plan, StepPrediction

    aside = [{"boxes": [box], "why": f"box '{box}' and box 'x' overlap by 0.100 m"}]
    return Plan("extract", other, "physics", (other,), (StepPrediction(other),), False, {}, 0, {"set_aside": aside})


def mask_of(p, box_id: str) -> np.ndarray:
    return p.masks == p.scene.box(box_id).mask_label


def test_redrawn_with_nothing_aside_it_is_perceptions_overlay_and_a_face_aside_is_hatched_grey(perceived):
    from scipy import ndimage

    from shelfpick.console.web.segmentation_view import draw_segmentation, segmentation_image

    cap, p = perceived
    assert np.array_equal(draw_segmentation(cap.rgb, p.masks, p.unexplained_labels, p.scene), p.overlay)
    top = max(p.scene.boxes, key=lambda b: b.position[2]).id
    out = segmentation_image(cap.rgb, p.overlay, p.masks, p.unexplained_labels, p.scene, {top})
    inside = ndimage.binary_erosion(mask_of(p, top), iterations=3)
    hatched = np.all(out[inside] == HATCH, axis=-1).mean()
    assert 0.1 < hatched < 0.5 and not np.all(p.overlay[inside] == HATCH, axis=-1).any()
    grey = out[inside & ~np.all(out == HATCH, axis=-1)].astype(int)
    tint = p.overlay[inside].astype(int)          # perception's: the box's saturated colour blended in
    spread = lambda px: np.median(px.max(axis=1) - px.min(axis=1))   # noqa: E731
    assert spread(grey) < spread(tint)
    far = ~ndimage.binary_dilation(mask_of(p, top), iterations=60)   # away from its outline and name
    assert np.array_equal(out[far], p.overlay[far])
    for unchanged in ({"nobody"}, set()):
        assert segmentation_image(cap.rgb, p.overlay, p.masks, None, p.scene, unchanged) is p.overlay
    assert segmentation_image(cap.rgb, p.overlay, None, None, p.scene, {top}) is p.overlay   # an older session
    assert segmentation_image(cap.rgb, p.overlay, p.masks[:-1], None, p.scene, {top}) is p.overlay


def test_perceptions_own_regions_stay_drawn_beside_the_faces_set_aside():
    """Matter perception found keeps its place and name; the set-aside mask is added after it."""
    from shelfpick.console.web.segmentation_view import draw_segmentation
    from shelfpick.perception.overlay import draw_unexplained
    from shelfpick.perception.scene import Box, Scene, Shelf, Unexplained

    rgb = np.full((60, 80, 3), 200, np.uint8)
    labels = np.zeros((60, 80), np.uint16)
    labels[5:25, 5:35], labels[30:55, 40:75] = 4, 9
    matter = np.zeros((60, 80), np.uint16)
    matter[30:55, 5:30] = 1
    u0 = Unexplained("u0", (-0.3, 0.0, 0.0), (-0.1, 0.0, 0.2), 600, 0.04, ((-0.3, -0.1, 0.0, 0.2, 0.0),), "")
    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (-0.3, 0.1, 0.1), mask_label=4),
                            Box("b6", (0.2, 0.2, 0.2), (0.2, 0.1, 0.1), mask_label=9)), unexplained=(u0,))
    out = draw_segmentation(rgb, labels, matter, scene, {"b6"})
    expected_matter = matter.copy()
    expected_matter[labels == 9] = 2
    from shelfpick.perception.overlay import draw_overlay
    kept = np.where(labels == 9, 0, labels).astype(np.uint16)
    assert np.array_equal(out, draw_unexplained(draw_overlay(rgb, kept, {4: "b0"}), expected_matter,
                                                ["u0", "aside-b6"]))
    assert np.all(out[32:53, 7:28] != rgb[32:53, 7:28], axis=-1).any()        # u0 still drawn


def test_the_label_images_are_stored_with_the_capture_and_an_older_log_gains_their_columns(tmp_path, perceived):
    import sqlite3

    from shelfpick.console.store.schema import SCHEMA_VERSION
    from shelfpick.console.store.sessions import SessionStore

    cap, p = perceived
    db = tmp_path / "s.sqlite"
    con = sqlite3.connect(db)           # a schema-3 log: captures without the two columns
    con.executescript("""
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        INSERT INTO meta VALUES ('schema', '3');
        CREATE TABLE sessions (id INTEGER PRIMARY KEY AUTOINCREMENT, started TEXT NOT NULL, source TEXT NOT NULL,
            n_boxes INTEGER NOT NULL, status TEXT NOT NULL, task TEXT, files TEXT);
        CREATE TABLE captures (session_id INTEGER PRIMARY KEY REFERENCES sessions(id), rgb TEXT NOT NULL, depth TEXT,
            camera TEXT NOT NULL, masks TEXT, masks_json TEXT, overlay TEXT, width INTEGER NOT NULL,
            height INTEGER NOT NULL);
        CREATE TABLE decisions (id INTEGER PRIMARY KEY AUTOINCREMENT, session_id INTEGER, plan_hash TEXT NOT NULL,
            decision TEXT NOT NULL, who TEXT NOT NULL, at TEXT NOT NULL, reason TEXT);
        CREATE TABLE robot_events (id INTEGER PRIMARY KEY AUTOINCREMENT, session_id INTEGER, plan_hash TEXT NOT NULL,
            at TEXT NOT NULL, kind TEXT NOT NULL, step INTEGER, box TEXT, detail TEXT);
        INSERT INTO sessions(started, source, n_boxes, status) VALUES ('2026-01-01', 'old', 0, 'captured');
        INSERT INTO captures VALUES (1, 'gone/rgb.png', NULL, 'gone/camera.json', NULL, NULL, NULL, 64, 48);
    """)
    con.close()
    with SessionStore(db) as store:
        old = store.list_sessions()
        sid = store.new_session("t", cap, p.scene, None, p.overlay, {}, labels=p.masks, matter=p.unexplained_labels)
        rec = store.load_session(sid)
    con = sqlite3.connect(db)
    assert con.execute("SELECT value FROM meta WHERE key='schema'").fetchone()[0] == str(SCHEMA_VERSION) == "4"
    row = con.execute("SELECT labels, matter FROM captures WHERE session_id=?", (sid,)).fetchone()
    assert con.execute("SELECT labels FROM captures WHERE session_id=1").fetchone()[0] is None
    con.close()
    assert len(old) == 1 and row[0] == f"s.sqlite.files/{sid}/labels.png"
    assert np.array_equal(rec.labels, p.masks) and rec.labels.dtype == np.uint16
    assert (rec.matter is None) == (p.unexplained_labels is None)
    (tmp_path / row[0]).unlink()                      # a deleted file: reported, the session still replays
    with SessionStore(db, readonly=True) as store:
        rec = store.load_session(sid)
    assert rec.labels is None and any("labels.png" in m for m in rec.missing_files)
    assert np.array_equal(rec.overlay, p.overlay)


def test_a_replay_and_its_export_show_the_faces_its_plans_set_aside_as_matter(tmp_path, perceived):
    from session_fixture import replaying

    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.web.replay import render_html
    from shelfpick.console.web.segmentation_view import draw_segmentation

    cap, p = perceived
    top = max(p.scene.boxes, key=lambda b: b.position[2]).id
    other = next(b for b in p.scene.ids if b != top)
    store = SessionStore(tmp_path / "r.sqlite")
    sid = store.new_session("t", cap, p.scene, None, p.overlay, {}, labels=p.masks, matter=p.unexplained_labels)
    plain = store.new_session("t", cap, p.scene, None, p.overlay, {}, labels=p.masks, matter=p.unexplained_labels)
    store.add_plan(sid, aside_plan(top, other))
    expected = draw_segmentation(cap.rgb, p.masks, p.unexplained_labels, p.scene, {top})
    try:
        with replaying(store, sid) as view:
            assert np.array_equal(view.operator.img_overlay.image, expected)
            assert np.array_equal(view.sessions.img_overlay.image, expected)
        with replaying(store, plain) as view:
            assert np.array_equal(view.operator.img_overlay.image, p.overlay)
        page = render_html(store.load_session(sid))
        assert "faces a plan set aside shown as unexplained matter" in page
        assert "set aside" not in render_html(store.load_session(plain))
    finally:
        store.close()


def test_the_live_view_redraws_the_image_when_plans_set_faces_aside_and_back_when_they_do_not(tmp_path, perceived):
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.web.segmentation_view import draw_segmentation
    from shelfpick.console.workflow.machine import PlanEntry, Workflow

    cap, p = perceived
    top = max(p.scene.boxes, key=lambda b: b.position[2]).id
    other = next(b for b in p.scene.ids if b != top)
    store = SessionStore(tmp_path / "live.sqlite")
    wf = Workflow(None, store, lambda truth, seed: None, "pw")
    app = ConsoleApp(wf, port=0)
    try:
        view = ClientView(app, app.server)
        with wf._lock:
            wf._set(capture=cap, overlay=p.overlay, labels=p.masks, matter=p.unexplained_labels, scene=p.scene,
                    target=other, plans={})
        view.render(wf.state)
        assert view.operator.img_overlay.image is p.overlay
        plan = aside_plan(top, other)
        with wf._lock:
            wf._set(plans={"physics": PlanEntry(plan, plan.content_hash())})
        view.render(wf.state)
        assert np.array_equal(view.operator.img_overlay.image,
                              draw_segmentation(cap.rgb, p.masks, p.unexplained_labels, p.scene, {top}))
        with wf._lock:
            wf._set(plans={})                       # a new target: no plan sets the face aside any more
        view.render(wf.state)
        assert np.array_equal(view.operator.img_overlay.image, p.overlay)
    finally:
        app.stop()
        store.close()
