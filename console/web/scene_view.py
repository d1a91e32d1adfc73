"""Drawing a shelf scene on a viser scene (server-wide or one client's) and animating previews.

Pure helpers around `viser.SceneApi`: the app decides what to draw, these
functions decide how (names, colours, translucency). The preview timeline is
built from `Predictor.preview` step results, so the 3D view replays what the
simulation recorded, not an interpolation.
"""
from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

SHELF_COLOR = (150, 130, 110)
TARGET_COLOR = (255, 200, 0)
RISK_COLOR = (230, 30, 30)
PREDICTED_COLOR = (40, 90, 230)   # outlines of where a verification expected the boxes that differ
PANEL = 0.02  # shelf board thickness drawn, m


def box_color(index: int) -> tuple[int, int, int]:
    """A distinct, stable colour per index: the segmentation overlay's palette
    (perception.overlay.palette), so a box is one colour in the 3D view and in the overlay."""
    h = (index * 0.618034) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.85, 0.95)
    return int(255 * r), int(255 * g), int(255 * b)


def colors_for(scene_or_ids: Any) -> dict[str, tuple[int, int, int]]:
    """Id -> colour. A perceived scene's boxes take their mask's overlay colour (`mask_label`);
    boxes without one (a scene file, a replayed look) take the colour of their place in the list."""
    boxes = getattr(scene_or_ids, "boxes", None)
    if boxes is None:
        return {bid: box_color(i) for i, bid in enumerate(scene_or_ids)}
    return {b.id: box_color(b.mask_label if b.mask_label is not None else i) for i, b in enumerate(boxes)}


def draw_shelf(scene_api: Any, shelf: Any, prefix: str = "/shelf") -> list:
    """Floor, back wall, side walls and top as thin translucent boards."""
    w, d, h, t = shelf.width, shelf.depth, shelf.height, PANEL
    boards = {
        "floor": ((w + 2 * t, d, t), (0.0, d / 2, -t / 2)),
        "top": ((w + 2 * t, d, t), (0.0, d / 2, h + t / 2)),
        "back": ((w + 2 * t, t, h + 2 * t), (0.0, d + t / 2, h / 2)),
        "left": ((t, d, h), (-w / 2 - t / 2, d / 2, h / 2)),
        "right": ((t, d, h), (w / 2 + t / 2, d / 2, h / 2)),
    }
    out = []
    for name, (dims, pos) in boards.items():
        out.append(scene_api.add_box(f"{prefix}/{name}", color=SHELF_COLOR, dimensions=dims,
                                     position=pos, opacity=0.25, cast_shadow=False,
                                     receive_shadow=False))
    return out


def draw_caption(scene_api: Any, shelf: Any, text: str, name: str = "/caption") -> Any:
    """A line above the shelf's front left corner saying what the 3D view shows (the shelf as seen,
    or a preview's predicted frame): every tab sees the one view, and a preview's last frame, boxes
    gone, looks like a shelf. Plain text (a label, never markup)."""
    return scene_api.add_label(name, text, position=(-shelf.width / 2, 0.0, shelf.height + 0.06),
                               anchor="bottom-left", font_screen_scale=1.0)


def draw_camera(scene_api: Any, camera: Any, image: np.ndarray | None = None,
                name: str = "/camera") -> Any:
    """The camera frustum at its pose in the shelf frame (OpenCV convention, like viser's)."""
    fov = 2.0 * math.atan2(camera.height / 2.0, camera.fy)
    return scene_api.add_camera_frustum(name, fov=fov, aspect=camera.width / camera.height,
                                        scale=0.1, thickness=0.004, color=(40, 40, 40), image=image,
                                        cast_shadow=False, receive_shadow=False,
                                        wxyz=tuple(camera.orientation),
                                        position=tuple(camera.position))


@dataclass
class BoxNodes:
    """The viser nodes of one box: the solid box, its id label, and highlight shells."""

    box: Any
    label: Any
    target: Any
    risk: Any


def draw_boxes(scene_api: Any, scene: Any, prefix: str = "/boxes") -> dict[str, BoxNodes]:
    """Each box coloured by id, labelled on its front face, with hidden target/risk shells that follow it."""
    colors = colors_for(scene)
    out: dict[str, BoxNodes] = {}
    for i, b in enumerate(scene.boxes):
        # nodes are named by position, not id: an id from a scene file is outside text ("a/label", "..")
        base = f"{prefix}/{i}"
        handle = scene_api.add_box(base, color=colors[b.id], dimensions=tuple(b.size),
                                   position=tuple(b.position), wxyz=tuple(b.orientation),
                                   cast_shadow=False, receive_shadow=False)
        # children follow the parent's pose during the preview animation
        # the id sits in the middle of the face the camera (and the operator) sees, just in front of
        # it: a label at a box's top edge reads as the box above and one click picks the wrong target
        # a face perception itself doubts (`perceived.contradicted`) says so where it stands
        label = scene_api.add_label(f"{base}/label", f"{b.id} ?" if b.contradicted else b.id, position=label_position(b),
                                    anchor="center-center", font_screen_scale=1.1)
        grow = (b.size[0] + 0.02, b.size[1] + 0.02, b.size[2] + 0.02)
        target = scene_api.add_box(f"{base}/target", color=TARGET_COLOR, dimensions=grow,
                                   wireframe=True, visible=False, cast_shadow=False)
        grow2 = (b.size[0] + 0.035, b.size[1] + 0.035, b.size[2] + 0.035)
        risk = scene_api.add_box(f"{base}/risk", color=RISK_COLOR, dimensions=grow2,
                                 wireframe=True, visible=False, cast_shadow=False)
        out[b.id] = BoxNodes(handle, label, target, risk)
    return out


def label_position(box: Any) -> tuple[float, float, float]:
    """Where a box's id is drawn, in the box's own frame: the centre of its front (local -y) face."""
    return (0.0, -box.size[1] / 2 - 0.002, 0.0)


UNEXPLAINED_COLOR = (120, 120, 120)


def draw_unexplained(scene_api: Any, scene: Any, prefix: str = "/unexplained") -> list:
    """Matter perception saw that no box explains (`Scene.unexplained`), where planning puts it
    (`planning.unexplained.obstacles`: the seen surface back to the back wall): translucent grey
    blocks with dark edges, told apart from every box, and one label per region ("u0 ?")."""
    from shelfpick.planning.unexplained import obstacles

    regions = getattr(scene, "unexplained", None) or ()
    out: list = []
    for i, (_, half, centre) in enumerate(obstacles(scene) if regions else ()):
        dims = tuple(2 * h for h in half)
        # named by position: a region id is outside text
        out.append(scene_api.add_box(f"{prefix}/{i}", color=UNEXPLAINED_COLOR, dimensions=dims, position=centre,
                                     opacity=0.35, cast_shadow=False, receive_shadow=False))
        out.append(scene_api.add_box(f"{prefix}/edge{i}", color=(50, 50, 50), dimensions=dims, position=centre,
                                     wireframe=True, cast_shadow=False))
    for k, u in enumerate(regions):
        top = ((u.min[0] + u.max[0]) / 2, u.min[1], u.max[2] + 0.03)
        out.append(scene_api.add_label(f"{prefix}/label{k}", f"{u.id} ?", position=top,
                                       anchor="bottom-center", font_screen_scale=1.1))
    return out


def draw_set_aside(scene_api: Any, aside: Any, prefix: str = "/aside") -> list:
    """Faces the planner set aside (`planning.set_aside.SetAside`: two faces no sample world can hold
    as perceived) drawn as what it planned with: unexplained matter from the seen face back to the
    wall, grey like the rest. The caller hides their boxes: a box drawn there would say the planner
    knows it stands, and after a preview it would hang in the air."""
    from dataclasses import replace

    regions = aside.regions()
    return draw_unexplained(scene_api, replace(aside.planned, unexplained=regions), prefix) if regions else []


def draw_outlines(scene_api: Any, boxes: Sequence[Any], prefix: str = "/predicted") -> list:
    """Wireframe boxes (blue) at the given poses: a step's predicted shelf over the observed one."""
    out = []
    for i, b in enumerate(boxes):   # named by position: ids are outside text
        out.append(scene_api.add_box(f"{prefix}/{i}", color=PREDICTED_COLOR, dimensions=tuple(b.size),
                                     position=tuple(b.position), wxyz=tuple(b.orientation),
                                     wireframe=True, cast_shadow=False, receive_shadow=False))
    return out


def risky_boxes(plan: Any, threshold: float = 0.0) -> set[str]:
    """Boxes a plan predicts may move (collapse or collision) in any step."""
    out: set[str] = set()
    for p in getattr(plan, "predicted", ()) or ():
        if p.collapse_prob > threshold or p.collision_prob > threshold:
            out.update(m for m in p.moved if m != p.box)
    return out


def _get(obj: Any, key: str, default: Any = None) -> Any:
    if isinstance(obj, Mapping):
        return obj.get(key, default)
    return getattr(obj, key, default)


@dataclass(frozen=True)
class Keyframe:
    step: int                      # index in the plan's sequence
    box: str                       # the box being pulled in this step
    t: float                       # seconds since the start of the preview (simulated time: real pace)
    poses: Mapping[str, tuple]     # id -> (position, wxyz) for boxes present
    collapsed: tuple[str, ...]     # boxes this step's simulation judged collapsed
    world: str = ""                # which sample world this step is shown in, in words


def timeline(preview: Iterable[Any], max_frames_per_step: int = 90,
             shown: Mapping[int, Mapping[str, Any]] | None = None, worlds: int | None = None) -> list[Keyframe]:
    """Flatten recorded step results (objects or their JSON) into keyframes at their recorded times.

    `shown`: step -> a recording of that step in a sample world where it collapses
    (console.workflow.planning_stage.collapse_worlds), played instead of the first world's; each
    keyframe says which world it shows. Frames are thinned only beyond
    `max_frames_per_step` (the recording is ~30 fps), so a pull plays at its real pace.
    """
    out: list[Keyframe] = []
    t0 = 0.0
    shown = shown or {}
    for i, step in enumerate(preview):
        alt = shown.get(i) or {}
        if alt.get("result") is not None:
            step = alt["result"]
            world = (f"collapses in {alt['collapsed_in']} world{'s' if alt['collapsed_in'] != 1 else ''} "
                     f"of {alt['of']}: shown in world {int(alt['world']) + 1}")
        elif alt:
            world = (f"collapses in {alt['collapsed_in']} world{'s' if alt['collapsed_in'] != 1 else ''} "
                     f"of {alt['of']} (not shown: this world holds)")
        else:
            world = "sample world 1" + (f" of {worlds}" if worlds else "")
        frames = list(_get(step, "frames", ()) or ())
        if not frames:
            continue
        stride = max(1, math.ceil(len(frames) / max_frames_per_step))
        keep = frames[::stride]
        if keep[-1] is not frames[-1]:
            keep.append(frames[-1])
        collapsed = tuple(_get(step, "collapsed", ()) or ())
        box = _get(step, "box", "")
        last = 0.0
        for fr in keep:
            t, poses = (fr[0], fr[1]) if not isinstance(fr, Mapping) else (fr["t"], fr["poses"])
            poses = {k: (tuple(v[0]), tuple(v[1])) for k, v in poses.items()}
            out.append(Keyframe(i, box, t0 + float(t), poses, collapsed, world))
            last = float(t)
        t0 += last + 0.3          # a short pause between pulls, so one step reads apart from the next
    return out


def frame_at(frames: Sequence[Keyframe], t: float) -> int:
    """Index of the last keyframe at or before time `t` (real-pace playback)."""
    import bisect

    return max(0, bisect.bisect_right([f.t for f in frames], t) - 1)


def visible_pose(pose: tuple | None, shelf: Any) -> bool:
    """A parked (taken-away) box is far outside the shelf: hide it."""
    if pose is None:
        return False
    x, y, z = pose[0]
    return (abs(x) < shelf.width + 1.0 and -1.5 < y < shelf.depth + 1.0 and -0.5 < z < shelf.height + 1.0)


def apply_keyframe(server: Any, nodes: Mapping[str, BoxNodes], frame: Keyframe, shelf: Any,
                   risk: set[str] | None = None, recorded: set[str] | None = None) -> None:
    """Move every box to the recorded pose in one atomic update; collapsing boxes turn red. A box
    missing from a frame was pulled or fell out of the shelf; one no frame of the preview records
    (`recorded`: the ids any frame has; faces the planner set aside) stays as perceived."""
    with server.atomic():
        for bid, n in nodes.items():
            if recorded is not None and bid not in recorded:
                continue
            pose = frame.poses.get(bid)
            show = visible_pose(pose, shelf)
            if show:
                n.box.position = np.asarray(pose[0], dtype=float)
                n.box.wxyz = np.asarray(pose[1], dtype=float)
            n.box.visible = show
            n.risk.visible = show and (bid in frame.collapsed or bool(risk and bid in risk))


def reset_boxes(server: Any, nodes: Mapping[str, BoxNodes], scene: Any,
                hidden: Iterable[str] = ()) -> None:
    """Back to the perceived poses; `hidden` (faces drawn as set-aside matter) stay hidden."""
    hidden = set(hidden)
    with server.atomic():
        for b in scene.boxes:
            n = nodes.get(b.id)
            if n is None:
                continue
            n.box.position = np.asarray(b.position, dtype=float)
            n.box.wxyz = np.asarray(b.orientation, dtype=float)
            n.box.visible = b.id not in hidden


__all__ = ["box_color", "colors_for", "draw_shelf", "draw_caption", "draw_camera", "draw_boxes", "draw_outlines", "draw_set_aside", "BoxNodes",
           "risky_boxes", "Keyframe", "timeline", "frame_at", "label_position", "apply_keyframe", "reset_boxes", "visible_pose"]
