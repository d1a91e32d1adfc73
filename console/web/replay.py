"""A stored session as ONE self-contained HTML file: opens in any browser, no server, no network.

Everything is inline: the images as base64 PNG, the plans side by side, the
supervisor's decisions, the robot's events and its actual outcome beside the
prediction, and a small SVG animation (front view, x-z) of each plan's
recorded preview with play, pause and a scrubber. No external URL appears in
the document, so it can be mailed, archived or opened on an air-gapped
machine.
"""
from __future__ import annotations

import base64
import colorsys
import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from shelfpick.perception.scene import Box, Scene, Shelf, quat_to_matrix
from shelfpick.planning.plan import Plan

from shelfpick.console.store.sessions import PlanRecord, SessionRecord
from shelfpick.console.workflow.machine import SECONDS_PER_BOX   # the estimate the console shows, defined once
from shelfpick.console.web.segmentation_view import segmentation_image, set_aside_boxes
from shelfpick.console.web.risk_text import pct, risk_words
from shelfpick.console.web.time_words import start_time_words

MAX_FRAMES_PER_STEP = 30


def _e(v: Any) -> str:
    return html.escape("" if v is None else str(v))


def png_data_uri(img: np.ndarray) -> str:
    import cv2

    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a.astype(np.uint8), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", a)
    if not ok:
        raise ValueError("cannot encode image as PNG")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def depth_colour(depth: np.ndarray) -> np.ndarray:
    """Metric depth -> RGB for a person (near = warm); no-data pixels black."""
    import cv2

    d = np.nan_to_num(np.asarray(depth, np.float32))
    valid = d > 0
    out = np.zeros(d.shape + (3,), np.uint8)
    if valid.any():
        lo, hi = np.percentile(d[valid], [1, 99])
        n = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
        col = cv2.applyColorMap((255 - n * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        out[valid] = cv2.cvtColor(col, cv2.COLOR_BGR2RGB)[valid]
    return out


def mask_colour(masks: np.ndarray) -> np.ndarray:
    m = np.asarray(masks)
    out = np.zeros(m.shape + (3,), np.uint8)
    for lab in np.unique(m):
        if lab:
            out[m == lab] = box_colour(int(lab))
    return out


def box_colour(index: int) -> tuple[int, int, int]:
    h = (index * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.45, 0.85)
    return int(r * 255), int(g * 255), int(b * 255)


# --------------------------------------------------------------------------
def _hull(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Convex hull (monotone chain), counter-clockwise."""
    pts = sorted(set(points))
    if len(pts) <= 2:
        return list(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return lower[:-1] + upper[:-1]


def front_polygon(box: Box, position: Sequence[float], wxyz: Sequence[float]) -> list[list[float]]:
    """The box's silhouette seen from the front (x right, z up)."""
    r = quat_to_matrix(wxyz)
    pts = []
    for sx in (-0.5, 0.5):
        for sy in (-0.5, 0.5):
            for sz in (-0.5, 0.5):
                loc = (sx * box.size[0], sy * box.size[1], sz * box.size[2])
                x = position[0] + sum(r[0][j] * loc[j] for j in range(3))
                z = position[2] + sum(r[2][j] * loc[j] for j in range(3))
                pts.append((round(x, 4), round(z, 4)))
    return [list(p) for p in _hull(pts)]


def _frames_of(step: Mapping) -> list[tuple[float, dict]]:
    """Recorded frames of one preview step: `[[t, {id: [pos, wxyz]}], ...]` (StepResult.to_json(frames=True))."""
    raw = step.get("frames") or []
    out = []
    for fr in raw:
        if isinstance(fr, (list, tuple)) and len(fr) == 2 and isinstance(fr[1], Mapping):
            out.append((float(fr[0]), dict(fr[1])))
        elif isinstance(fr, Mapping) and isinstance(fr.get("poses"), Mapping):
            out.append((float(fr.get("t", 0.0)), dict(fr["poses"])))
    return out


Polygon = list[list[float]]   # a front-view silhouette: [[x, z], ...]


@dataclass(frozen=True, eq=False)
class FrontKey:
    """One keyframe of the replay's front-view animation: every box's silhouette at one moment."""

    label: str
    step: int                          # index in the plan's sequence; -1: the shelf as captured
    polys: Mapping[str, Polygon]       # box id -> silhouette, for the boxes still on the shelf
    pulled: str | None = None          # the box this step pulls
    collapsed: tuple[str, ...] = field(default_factory=tuple)   # what this step's simulation judged collapsed


def keyframes(scene: Scene, sequence: Sequence[str], preview: list | None) -> list[FrontKey]:
    """Front-view polygons per keyframe: the recorded preview when stored, else a step-by-step removal."""
    boxes = {b.id: b for b in scene.boxes}
    keys: list[FrontKey] = []
    still = {b.id: front_polygon(b, b.position, b.orientation) for b in scene.boxes}
    keys.append(FrontKey("start", -1, still))
    recorded = bool(preview) and any(_frames_of(s) for s in preview if isinstance(s, Mapping))
    if recorded:
        removed: set[str] = set()
        for i, step in enumerate(preview or []):
            if not isinstance(step, Mapping):
                continue
            world = ""
            alt = step.get("collapse_world")
            if isinstance(alt, Mapping):          # the live page showed this step in a world where it collapses
                world = world_words(alt)
                if isinstance(alt.get("result"), Mapping) and _frames_of(alt["result"]):
                    step = {**alt["result"], "box": step.get("box", alt["result"].get("box"))}
            frames = _frames_of(step)
            if len(frames) > MAX_FRAMES_PER_STEP:
                idx = np.linspace(0, len(frames) - 1, MAX_FRAMES_PER_STEP).round().astype(int)
                frames = [frames[j] for j in sorted(set(idx.tolist()))]
            box_id = step.get("box", sequence[i] if i < len(sequence) else "?")
            for t, poses in frames:
                polys = {}
                for bid, pose in poses.items():
                    if bid not in boxes or bid in removed:
                        continue
                    try:
                        pos, quat = pose[0], pose[1]
                    except (TypeError, IndexError, KeyError):
                        continue
                    if abs(pos[0]) > 10 or abs(pos[2]) > 10:  # parked off the shelf
                        continue
                    polys[bid] = front_polygon(boxes[bid], pos, quat)
                keys.append(FrontKey(f"step {i + 1}: pull {box_id}, " + (f"{world}, " if world else "")
                                     + f"t={t:.2f} s", i, polys, box_id,
                                     tuple(step.get("collapsed") or ())))
            removed.add(str(box_id))
    else:
        gone: set[str] = set()
        for i, bid in enumerate(sequence):
            gone.add(bid)
            keys.append(FrontKey(f"step {i + 1}: {bid} removed (no recorded preview)", i,
                                 {k: v for k, v in still.items() if k not in gone}, bid))
    return keys


def world_words(alt: Mapping[str, Any]) -> str:
    """Which sample world a risky step is shown in, in the words of the live preview
    (console.web.scene_view.timeline): "collapses in 1 world of 10: shown in world 4"."""
    n, of = int(alt.get("collapsed_in", 0)), alt.get("of")
    head = f"collapses in {n} world{'s' if n != 1 else ''} of {of}"
    if alt.get("result") is not None and alt.get("world") is not None:
        return f"{head}: shown in world {int(alt['world']) + 1}"
    return f"{head} (not shown: this world holds)"


def shown_worlds(preview: Sequence[Any] | None) -> dict[int, dict]:
    """step -> the stored world a risky step is shown in (`collapse_world` of a stored preview step,
    console.store.sessions.add_preview_worlds), in the shape the live preview takes (PlanEntry.collapse_steps)."""
    return {i: dict(s["collapse_world"]) for i, s in enumerate(preview or ())
            if isinstance(s, Mapping) and isinstance(s.get("collapse_world"), Mapping)}


def _svg(scene: Scene, keys: list[FrontKey], anim_id: str, target: str | None,
         at_risk: Iterable[str]) -> str:
    s = scene.shelf
    tops = [max(c[2] for c in b.corners()) for b in scene.boxes] or [0.5]
    zmax = min(s.height, max(tops) + 0.25)
    x0, x1 = -s.width / 2 - 0.05, s.width / 2 + 0.05
    lowest = min((z for k in keys for poly in k.polys.values() for _, z in poly), default=0.0)
    z0, z1 = max(min(-0.05, lowest - 0.03), -1.0), zmax + 0.05   # boxes that fall off stay in view
    w, h = x1 - x0, z1 - z0
    risk = set(at_risk)
    ids = [b.id for b in scene.boxes]
    parts = [f'<svg class="anim" id="{anim_id}-svg" viewBox="{x0:.3f} {-z1:.3f} {w:.3f} {h:.3f}" '
             f'preserveAspectRatio="xMidYMid meet" role="img" aria-label="front view of the shelf">',
             f'<rect x="{-s.width / 2:.3f}" y="{-zmax:.3f}" width="{s.width:.3f}" height="{zmax:.3f}" '
             f'fill="#f4efe8" stroke="#8b7355" stroke-width="0.01"/>',
             f'<line x1="{x0:.3f}" y1="0" x2="{x1:.3f}" y2="0" stroke="#5a4630" stroke-width="0.02"/>']
    for i, bid in enumerate(ids):
        r, g, b = box_colour(i + 1)
        stroke = "#e01e1e" if bid in risk else ("#d4a000" if bid == target else "#333")
        width = 0.012 if bid in risk or bid == target else 0.004
        parts.append(f'<polygon data-box="{_e(bid)}" points="" fill="rgb({r},{g},{b})" stroke="{stroke}" '
                     f'stroke-width="{width}" />')
        parts.append(f'<text data-label="{_e(bid)}" x="0" y="0" font-size="0.04" text-anchor="middle" '
                     f'fill="#111">{_e(bid)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def _animation(scene: Scene, plan: Plan, preview: list | None, anim_id: str) -> str:
    keys = keyframes(scene, plan.sequence, preview)
    at_risk = {m for p in plan.predicted for m in p.moved if p.collapse_prob > 0}
    data = json.dumps({"keys": [{"label": k.label, "polys": {b: [[x, -z] for x, z in poly]
                                                               for b, poly in k.polys.items()}}
                                for k in keys]}, separators=(",", ":"))
    # outside text (box ids) inside a <script> element: no "<" at all, so no tag can end or open it
    data = data.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    return (f'<div class="animbox">{_svg(scene, keys, anim_id, plan.target, at_risk)}'
            f'<div class="controls"><button type="button" id="{anim_id}-play">Play</button>'
            f'<input type="range" id="{anim_id}-scrub" min="0" max="{len(keys) - 1}" value="0" step="1">'
            f'<span id="{anim_id}-label"></span></div>'
            f'<script type="application/json" id="{anim_id}-data">{data}</script>{_world_note(plan, preview)}</div>')


def _world_note(plan: Plan, preview: list | None) -> str:
    """Under the animation: each risky step and the sample world it is shown in (as the live preview)."""
    worlds = shown_worlds(preview)
    items = [f"step {k + 1} ({_e(plan.sequence[k] if k < len(plan.sequence) else '?')}): {_e(world_words(w))}"
             for k, w in sorted(worlds.items())]
    return f'<p class="small worlds">{"<br>".join(items)}</p>' if items else ""


# --------------------------------------------------------------------------
def _pct(v: float | None) -> str:
    return "—" if v is None else pct(v)


def decided_planner(d: Mapping[str, Any], rec: SessionRecord) -> str | None:
    """Which plan a decision was about, by planner: the decision's own record when it names one,
    else the one plan of the session with its hash, else (two planners gave the same sequence) the
    plan the robot then ran for an approval; None when the record cannot tell."""
    if isinstance(d.get("planner"), str):
        return d["planner"]
    same = {pr.plan.planner for pr in rec.plans if pr.hash == d.get("plan_hash")}
    if len(same) == 1:
        return next(iter(same))
    out = rec.outcome or {}
    if d.get("decision") == "approve" and out.get("plan") == d.get("plan_hash") and out.get("planner") in same:
        return str(out["planner"])
    return None


def approved_plans(rec: SessionRecord) -> set[tuple[str, str]]:
    """(planner, hash) of every approved plan: one card marked even when two planners gave one sequence."""
    return set(decided_plans(rec, "approve"))


def decided_plans(rec: SessionRecord, decision: str) -> dict[tuple[str, str], list[str]]:
    """(planner, hash) of every plan given `decision` ("approve" or "reject") -> who gave it."""
    out: dict[tuple[str, str], list[str]] = {}
    for d in rec.decisions:
        if d["decision"] == decision:
            planner = decided_planner(d, rec)
            for pr in rec.plans:
                if pr.hash == d["plan_hash"] and planner in (None, pr.plan.planner):
                    out.setdefault((pr.plan.planner, pr.hash), []).append(str(d.get("who") or "?"))
    return out


def _plan_card(pr: PlanRecord, rec: SessionRecord, idx: int, approved: set[tuple[str, str]],
               rejected: Mapping[tuple[str, str], list[str]] | None = None) -> str:
    plan = pr.plan
    pred = {p.box: p for p in plan.predicted}
    rows = []
    for i, box in enumerate(plan.sequence):
        p = pred.get(box)
        rows.append(f"<tr><td>{i + 1}</td><td>{_e(box)}</td><td>{_pct(p.collapse_prob if p else None)}</td>"
                    f"<td>{_pct(p.collision_prob if p else None)}</td>"
                    f"<td>{_e(', '.join(p.moved)) if p and p.moved else ''}</td></tr>")
    timing = dict(plan.timing)
    plan_s = (float(timing["wall_s"]) + float(timing.get("setup_s", 0.0)) if "wall_s" in timing else
              timing.get("total", timing.get("planning", sum(v for v in timing.values()
                                                              if isinstance(v, (int, float))))))
    badge = ' <span class="ok">approved</span>' if (plan.planner, pr.hash) in approved else ""
    by = (rejected or {}).get((plan.planner, pr.hash))
    if by:
        badge += f' <span class="err rejected">rejected by {_e(", ".join(dict.fromkeys(by)))}</span>'
    check = _scene_check(plan)
    return (f'<div class="card"><h3>{_e(plan.planner)} plan{badge}</h3>'
            f'<p class="small">hash <code>{_e(pr.hash)}</code> · {_e(plan.task)}'
            f'{(" " + _e(plan.target)) if plan.target else ""} · '
            f'{"safe" if plan.safe else "<b>no safe solution</b>"}</p>'
            f'<p>boxes removed: <b>{len(plan.sequence)}</b> · {_e(risk_words(plan))}<br>'
            f'estimated execution: <b>{len(plan.sequence) * SECONDS_PER_BOX:.0f} s</b> · '
            f'planning time: <b>{float(plan_s or 0.0):.2f} s</b></p>'
            f'<table><tr><th>step</th><th>box</th><th>collapse</th><th>collision</th><th>expected to move</th></tr>'
            f'{"".join(rows)}</table>{check}'
            f'<h4>Predicted outcome (front view)</h4>{_animation(rec.scene, plan, pr.preview, f"anim{idx}")}</div>')


def _scene_check(plan: Plan) -> str:
    """What the planner found does not stand as seen, and what the physics adjusted (escaped)."""
    extra = dict(plan.extra or {})
    check = extra.get("scene_check") or {}
    out = ""
    if isinstance(check, Mapping) and not check.get("stands_as_seen", True):
        items = "".join(f'<li>{_e("box " + str(p.get("box")) if p.get("box") else "the scene")} '
                        f'{_e(p.get("what", ""))}</li>' for p in check.get("problems") or [] if isinstance(p, Mapping))
        out += (f'<p class="err"><b>The shelf does not stand as seen</b>: no plan on it is safe.</p>'
                f'<ul class="scene-problems">{items}</ul>')
    repairs = extra.get("repairs") or []
    if repairs:
        out += f'<p class="small">perceived scene adjusted by the physics: {_e("; ".join(map(str, repairs)))}</p>'
    return out


def _outcome(rec: SessionRecord) -> str:
    out = rec.outcome
    if not out:
        return "<p><i>The robot did not run in this session.</i></p>"
    plan_hash = out.get("plan")
    pred: dict[str, Any] = {}
    for pr in rec.plans:
        if pr.hash == plan_hash:
            pred = {p.box: p for p in pr.plan.predicted}
    steps = out.get("steps") or []
    seq = out.get("sequence") or [s.get("box") for s in steps]
    rows = []
    for i, box in enumerate(seq):
        st = steps[i] if i < len(steps) and isinstance(steps[i], Mapping) else {}
        det = st.get("detail") or {}
        actual_collapse = _seen(det.get("collapsed_ids", det.get("collapsed")) or [], set(rec.scene.ids))
        disp = det.get("displacement") or {}
        max_disp = max((float(v) for v in disp.values()), default=0.0) if isinstance(disp, Mapping) else 0.0
        p = pred.get(box)
        status = st.get("status") or ("done" if box in (out.get("completed") or []) else "not run")
        cls = "bad" if actual_collapse or status in ("error", "unknown") else ("ok" if status == "done" else "")
        rows.append(f'<tr class="{cls}"><td>{i + 1}</td><td>{_e(box)}</td>'
                    f'<td>{_pct(p.collapse_prob if p else None)}</td>'
                    f'<td>{_e(", ".join(p.moved)) if p and p.moved else ""}</td>'
                    f'<td>{_e(status)}</td><td>{_e(actual_collapse) or "none"}</td>'
                    f'<td>{max_disp * 100:.1f} cm</td><td>{_e(det.get("message", ""))}</td></tr>')
    head = ("success" if out.get("ok") else "interrupted: the console stopped during the run"
            if out.get("interrupted") else "stopped by Stop robot" if out.get("stopped") else "not completed")
    return (f'<p><b>{head}</b> · plan <code>{_e(plan_hash)}</code> ({_e(out.get("planner", "?"))}) · completed: '
            f'{_e(", ".join(out.get("completed") or [])) or "none"}'
            + (f'<br><span class="err">{_e(out.get("error"))}</span>' if out.get("error") else "") + "</p>"
            '<table><tr><th>step</th><th>box</th><th>predicted collapse</th><th>predicted to move</th>'
            '<th>actual</th><th>actually collapsed</th><th>largest displacement</th><th>note</th></tr>'
            + "".join(rows) + "</table>")


def _seen(ids: Iterable[Any], seen: set[str]) -> str:
    """Collapsed boxes by the ids perception gave them; one the camera never saw is said so (issue 33)."""
    from shelfpick.console.robot.drivers import seen_names

    return seen_names([str(b) if str(b) in seen else None for b in ids])


def _look_svg(shelf: Shelf, predicted: Scene | None, observed: Scene | None, differ_p: set[str],
              differ_o: set[str]) -> str:
    """Front view of one look: observed boxes filled, predicted poses as dashed blue outlines
    (thick where the box differs), observed boxes that differ outlined in red."""
    boxes = [("o", b) for b in (observed.boxes if observed else ())] + \
            [("p", b) for b in (predicted.boxes if predicted else ())]
    polys = [(k, b, front_polygon(b, b.position, b.orientation)) for k, b in boxes]
    zs = [z for _, _, poly in polys for _, z in poly] or [0.0, 0.5]
    x0, x1 = -shelf.width / 2 - 0.05, shelf.width / 2 + 0.05
    z0, z1 = max(min(-0.05, min(zs) - 0.03), -1.0), min(shelf.height, max(zs) + 0.1) + 0.05
    parts = [f'<svg class="look" viewBox="{x0:.3f} {-z1:.3f} {x1 - x0:.3f} {z1 - z0:.3f}" '
             f'preserveAspectRatio="xMidYMid meet" role="img" aria-label="predicted vs observed">',
             f'<line x1="{x0:.3f}" y1="0" x2="{x1:.3f}" y2="0" stroke="#5a4630" stroke-width="0.02"/>']
    for i, (kind, b, poly) in enumerate(polys):
        pts = " ".join(f"{x:.4f},{-z:.4f}" for x, z in poly)
        if kind == "o":
            r, g, bl = box_colour(i + 1)
            stroke, w = ("#e01e1e", 0.012) if b.id in differ_o else ("#333", 0.004)
            parts.append(f'<polygon data-observed="{_e(b.id)}" points="{pts}" fill="rgb({r},{g},{bl})" '
                         f'fill-opacity="0.8" stroke="{stroke}" stroke-width="{w}"/>')
            cx = sum(x for x, _ in poly) / len(poly)
            cz = sum(z for _, z in poly) / len(poly)
            parts.append(f'<text x="{cx:.4f}" y="{-cz + 0.015:.4f}" font-size="0.035" text-anchor="middle">'
                         f'{_e(b.id)}</text>')
        else:
            w = 0.012 if b.id in differ_p else 0.005
            parts.append(f'<polygon data-predicted="{_e(b.id)}" points="{pts}" fill="none" stroke="#1e5ae0" '
                         f'stroke-width="{w}" stroke-dasharray="0.02,0.012"/>')
    parts.append("</svg>")
    return "".join(parts)


def _looks(rec: SessionRecord) -> str:
    """Each verified step: the verdict, what differed, and predicted (outlines) over observed (filled)."""
    if not rec.verifications:
        return "<p><i>No look after a step was recorded in this session.</i></p>"
    out = []
    for v in rec.verifications:
        verdict = v.get("verdict") or {}
        diffs = [d for d in verdict.get("boxes", []) if d.get("status") != "ok"]
        differ_p = {d["predicted"] for d in diffs if d.get("predicted") and d.get("status") in ("moved", "missing")}
        differ_o = {d["observed"] for d in diffs if d.get("observed") and d.get("status") in ("moved", "new")}
        rows = "".join(f'<tr><td>{_e(d.get("predicted") or "—")}</td><td>{_e(d.get("observed") or "—")}</td>'
                       f'<td>{100 * float(d.get("displacement_m", 0)):.1f} cm</td>'
                       f'<td>{float(d.get("rotation_deg", 0)):.0f}°</td><td>{_e(d.get("status"))}</td></tr>'
                       for d in diffs)
        table = ('<table><tr><th>predicted box</th><th>observed box</th><th>off by</th><th>turned</th>'
                 f'<th></th></tr>{rows}</table>') if rows else ""
        svg = _look_svg(rec.scene.shelf, v.get("predicted"), v.get("observed"), differ_p, differ_o)
        cls = "ok" if v.get("within") else "err"
        out.append(f'<div class="card" data-look="{int(v["step"])}"><p class="{cls}"><b>'
                   f'{"✓" if v.get("within") else "⚠"} {_e(verdict.get("summary", ""))}</b></p>'
                   f'<p class="small">plan <code>{_e(v.get("plan_hash"))}</code> · run {_e(v.get("run") or "")}'
                   f' · {_e(start_time_words(v.get("at")))}</p>{svg}{table}</div>')
    return ('<p class="small">After each step the console looked again: observed boxes filled (red outline: '
            'differs), the plan\'s predicted poses as dashed blue outlines.</p><div class="row">'
            + "".join(out) + "</div>")


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:1.5em;color:#222;background:#fafafa}
h1{margin-bottom:.2em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
.row{display:flex;flex-wrap:wrap;gap:1em} .card{background:#fff;border:1px solid #ddd;border-radius:6px;
padding:.8em 1em;flex:1 1 420px;min-width:320px}
figure{margin:0;flex:1 1 300px;max-width:48%} figure img{width:100%;border:1px solid #ccc}
figcaption{font-size:.85em;color:#555} table{border-collapse:collapse;font-size:.9em;margin:.4em 0}
td,th{border:1px solid #ddd;padding:.2em .5em;text-align:left} th{background:#f0f0f0}
tr.bad td{background:#fde8e8} tr.ok td{background:#eaf7ea} .ok{color:#197a19} .err{color:#b00}
.small{font-size:.85em;color:#555} svg.anim{width:100%;height:340px;background:#fff;border:1px solid #ddd}
.controls{display:flex;gap:.6em;align-items:center;margin:.3em 0} .controls input{flex:1}
svg.look{width:100%;height:300px;background:#fff;border:1px solid #ddd}
code{background:#f2f2f2;padding:0 .2em}
"""

_JS = """
(function(){
  document.querySelectorAll('script[id$="-data"]').forEach(function(el){
    var id = el.id.slice(0, -5), data = JSON.parse(el.textContent), keys = data.keys;
    var svg = document.getElementById(id + '-svg'), scrub = document.getElementById(id + '-scrub');
    var label = document.getElementById(id + '-label'), play = document.getElementById(id + '-play');
    var polys = {}, texts = {}, timer = null;
    svg.querySelectorAll('polygon[data-box]').forEach(function(p){ polys[p.getAttribute('data-box')] = p; });
    svg.querySelectorAll('text[data-label]').forEach(function(t){ texts[t.getAttribute('data-label')] = t; });
    function show(i){
      var k = keys[i]; label.textContent = (i + 1) + '/' + keys.length + '  ' + k.label;
      Object.keys(polys).forEach(function(b){
        var pts = k.polys[b], p = polys[b], t = texts[b];
        if (!pts){ p.style.display = 'none'; t.style.display = 'none'; return; }
        p.style.display = ''; t.style.display = '';
        p.setAttribute('points', pts.map(function(q){ return q[0] + ',' + q[1]; }).join(' '));
        var cx = 0, cy = 0; pts.forEach(function(q){ cx += q[0]; cy += q[1]; });
        t.setAttribute('x', cx / pts.length); t.setAttribute('y', cy / pts.length + 0.015);
      });
    }
    function stop(){ if (timer){ clearInterval(timer); timer = null; play.textContent = 'Play'; } }
    play.addEventListener('click', function(){
      if (timer){ stop(); return; }
      if (+scrub.value >= keys.length - 1) scrub.value = 0;
      play.textContent = 'Pause';
      timer = setInterval(function(){
        var i = +scrub.value + 1;
        if (i >= keys.length){ stop(); return; }
        scrub.value = i; show(i);
      }, 120);
    });
    scrub.addEventListener('input', function(){ stop(); show(+scrub.value); });
    show(0);
  });
})();
"""


def render_html(rec: SessionRecord) -> str:
    """The whole replay page as a string (no external reference of any kind)."""
    images = []
    if rec.capture is not None:
        images.append(("Captured RGB", rec.capture.rgb))
    aside = set_aside_boxes([p.plan for p in rec.plans])
    overlay = segmentation_image(rec.capture.rgb if rec.capture is not None else None, rec.overlay, rec.labels,
                                 rec.matter, rec.scene, aside)
    if overlay is not None:
        caption = "Segmentation overlay (masks, rectangles, box ids)"
        if overlay is not rec.overlay:
            caption += "; faces a plan set aside shown as unexplained matter (aside-…?)"
        images.append((caption, overlay))
    if rec.capture is not None and rec.capture.depth is not None:
        images.append(("Depth (near = warm)", depth_colour(rec.capture.depth)))
    if rec.capture is not None and rec.capture.masks is not None:
        images.append(("Ground-truth masks (rendered capture)", mask_colour(rec.capture.masks)))
    figs = "".join(f'<figure><img alt="{_e(c)}" src="{png_data_uri(img)}"><figcaption>{_e(c)}</figcaption></figure>'
                   for c, img in images) or "<p><i>No images stored.</i></p>"
    if rec.missing_files:
        figs += f'<p class="err">missing files: {_e(", ".join(rec.missing_files))}</p>'
    approved = approved_plans(rec)
    rejected = decided_plans(rec, "reject")
    cards = "".join(_plan_card(pr, rec, i, approved, rejected) for i, pr in enumerate(rec.plans)) \
        or "<p><i>No plans in this session.</i></p>"
    dec_rows = "".join(f'<tr><td>{_e(start_time_words(d["at"]))}</td><td>{_e(d["who"])}</td><td>{_e(d["decision"])}</td>'
                       f'<td>{_e(decided_planner(d, rec) or "")} <code>{_e(d["plan_hash"])}</code></td>'
                       f'<td>{_e(d.get("reason") or "")}</td></tr>'
                       for d in rec.decisions)
    decisions = (f'<table><tr><th>when</th><th>who</th><th>decision</th><th>plan</th><th>reason</th></tr>'
                 f'{dec_rows}</table>') if dec_rows else "<p><i>No decisions.</i></p>"
    ev_rows = "".join(
        f'<tr><td>{_e(start_time_words(e["at"]))}</td><td>{_e(e["kind"])}</td><td>{"" if e["step"] is None else e["step"] + 1}</td>'
        f'<td>{_e(e["box"] or "")}</td><td class="small">{_e(_brief(e["detail"]))}</td></tr>'
        for e in rec.robot_events)
    events = (f'<table><tr><th>when</th><th>event</th><th>step</th><th>box</th><th>detail</th></tr>'
              f'{ev_rows}</table>') if ev_rows else "<p><i>No robot events.</i></p>"
    perc = ""
    if rec.perception:
        warn = rec.perception.get("warnings") or []
        perc = "<p class='small'>perception warnings: " + (_e("; ".join(map(str, warn))) or "none") + "</p>"
    scene_rows = "".join(
        f"<tr><td>{_e(b.id)}</td><td>{', '.join(f'{v:.3f}' for v in b.size)}</td>"
        f"<td>{', '.join(f'{v:.3f}' for v in b.position)}</td><td>{'yes' if b.depth_known else 'no'}</td></tr>"
        for b in rec.scene.boxes)
    title = f"shelfpick session {rec.id}"
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width,initial-scale=1"><title>{_e(title)}</title>'
            f'<style>{_CSS}</style></head><body>'
            f'<h1>{_e(title)}</h1><p>started {_e(start_time_words(rec.started))} · source <code>{_e(rec.source)}</code> · status '
            f'<b>{_e(rec.status)}</b> · {rec.n_boxes} boxes' + (f' · {_e(rec.task)}' if rec.task else "") + '</p>'
            f'<h2>Capture</h2><div class="row">{figs}</div>{perc}'
            f'<h2>Perceived scene</h2><table><tr><th>box</th><th>size (m)</th><th>centre (m, shelf frame)</th>'
            f'<th>depth seen</th></tr>{scene_rows}</table>'
            f'<h2>Plans</h2><div class="row">{cards}</div>'
            f'<h2>Decisions</h2>{decisions}'
            f'<h2>Robot: actual outcome vs prediction</h2>{_outcome(rec)}'
            f'<h2>Looks after each step: predicted vs observed</h2>{_looks(rec)}'
            f'<h3>Robot events</h3>{events}'
            f'<p class="small">Exported by shelfpick replay; self-contained (no network needed).</p>'
            f'<script>{_JS}</script></body></html>')


def _brief(detail: Any, limit: int = 160) -> str:
    if not detail:
        return ""
    if isinstance(detail, Mapping):
        keep = {k: v for k, v in detail.items() if k not in ("displacement", "rotation_deg", "frames")}
        s = json.dumps(keep, separators=(",", ":"), default=str)
    else:
        s = str(detail)
    return s if len(s) <= limit else s[:limit - 1] + "…"


def export_html(rec: SessionRecord, out: str | Path) -> Path:
    """Write the replay of one session to `out` (folders created)."""
    from shelfpick.perception.scene import output_path, write_text

    output_path(out, "--html")          # a device, FIFO or folder is refused before the page is built
    return write_text(out, render_html(rec), "--html")


__all__ = ["render_html", "export_html", "keyframes", "FrontKey", "front_polygon", "png_data_uri", "shown_worlds",
           "world_words"]
