"""The JSON Schema files in docs/schemas/ describe what the loaders write and read: the demo shelves,
documents the code writes (scene, camera, plan with provenance) validate; a document the schema
refuses is one the loader refuses too (the schema is never stricter than the code)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

jsonschema = pytest.importorskip("jsonschema")
from referencing import Registry, Resource  # noqa: E402  (jsonschema >= 4.18 depends on it)

from shelfpick.perception.errors import FormatError  # noqa: E402
from shelfpick.perception.scene import Box, Camera, Scene, Shelf  # noqa: E402
from shelfpick.planning.plan import Plan, StepPrediction  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCHEMAS = ROOT / "docs" / "schemas"
CORPUS = ROOT / "tests" / "fuzz_corpus"


def load_schemas() -> dict[str, dict]:
    return {name: json.loads((SCHEMAS / f"{name}.schema.json").read_text()) for name in ("scene", "plan", "camera")}


@pytest.fixture(scope="module")
def validators() -> dict:
    docs = load_schemas()
    registry = Registry().with_resources((d["$id"], Resource.from_contents(d)) for d in docs.values())
    cls = jsonschema.Draft202012Validator
    return {name: cls(doc, registry=registry) for name, doc in docs.items()}


def errors(validator, doc) -> list[str]:
    return [e.message for e in validator.iter_errors(doc)]


def tiny_scene() -> Scene:
    cam = Camera(640, 480, 600.0, 600.0, 320.0, 240.0)
    return Scene(Shelf(), (Box("a", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),
                           Box("b", (0.2, 0.2, 0.2), (0.0, 0.1, 0.3), mass=1.5, depth_known=False, mask_label=2)),
                 camera=cam, source={"made": "in code"})


def test_the_schemas_are_valid_draft_2020_12():
    for doc in load_schemas().values():
        jsonschema.Draft202012Validator.check_schema(doc)


def test_demo_shelves_and_their_round_trip_validate(validators):
    demos = sorted((ROOT / "static" / "demo").glob("*.json"))
    assert demos
    for path in demos:
        raw = json.loads(path.read_text())
        assert errors(validators["scene"], raw) == [], path
        assert errors(validators["scene"], Scene.load(path).to_json()) == [], path


def test_documents_the_code_writes_validate(validators):
    scene = tiny_scene()
    assert errors(validators["scene"], scene.to_json()) == []
    assert errors(validators["camera"], scene.camera.to_json()) == []
    plan = Plan("extract", "a", "physics", ("b", "a"), (StepPrediction("b"), StepPrediction("a", 0.1, 0.0, ("b",))),
                safe=False, timing={"total": 1.5}, seed=3).with_provenance(scene, samples=10, risk=0.0)
    doc = plan.to_json()
    assert errors(validators["plan"], doc) == []
    assert Plan.from_json(doc).provenance["scene_hash"] == doc["provenance"]["scene_hash"]
    clear = Plan("clear", None, "heuristic", ("b", "a"))
    assert errors(validators["plan"], clear.to_json()) == []


def test_a_plan_from_make_plan_validates(validators):
    from shelfpick.planning.planner import make_plan

    scene = tiny_scene()
    plan = make_plan(scene, "extract", "a", planner="heuristic").with_provenance(scene)
    assert errors(validators["plan"], json.loads(json.dumps(plan.to_json()))) == []


def test_old_plans_without_provenance_still_load_and_validate(validators):
    old = {"format": "shelfpick.plan/1", "task": "extract", "target": "b3", "planner": "physics",
           "sequence": ["b5", "b3"]}
    assert errors(validators["plan"], old) == []
    assert Plan.from_json(old).provenance == {}


@pytest.mark.parametrize("kind, doc", [
    ("plan", {"format": "shelfpick.plan/1", "task": "clear", "target": "b1", "planner": "x", "sequence": []}),
    ("plan", {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "x", "sequence": ["a", "a"]}),
    ("plan", {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "x", "sequence": ["a"],
              "seed": True}),
    ("plan", {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "x", "sequence": ["a"],
              "predicted": [{"box": "a", "collapse_prob": 1.5}]}),
    ("plan", {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "x", "sequence": ["a"],
              "provenance": {"scene_hash": "not-a-hash"}}),
    ("scene", {"format": "shelfpick.scene/1", "shelf": {"width": 1, "depth": 0.3, "height": 0}, "boxes": []}),
    ("scene", {"format": "shelfpick.scene/1", "shelf": {"width": 1, "depth": 0.3, "height": 1},
               "boxes": [{"id": "", "size": [0.1, 0.1, 0.1], "position": [0, 0.1, 0.05]}]}),
    ("scene", {"format": "shelfpick.scene/1", "shelf": {"width": 1, "depth": 0.3, "height": 1},
               "boxes": [{"id": "a", "size": [0.1, -0.1, 0.1], "position": [0, 0.1, 0.05]}]}),
    ("camera", {"format": "shelfpick.camera/1", "width": 640.5, "height": 480, "fx": 1, "fy": 1, "cx": 0, "cy": 0,
                "pose": {"position": [0, 0, 0], "orientation": [1, 0, 0, 0]}}),
])
def test_what_the_schema_refuses_the_loader_refuses(validators, kind, doc):
    assert errors(validators[kind], doc)
    loader = {"plan": Plan.from_json, "scene": Scene.from_json, "camera": Camera.from_json}[kind]
    with pytest.raises(FormatError):
        loader(doc)


def test_fuzz_corpus_documents_refused_by_the_schema_are_refused_by_the_loader(validators):
    """Over the 113-case corpus: never a document the schema refuses and the loader takes."""
    loaders = {"scene": Scene.from_json, "plan": Plan.from_json, "camera": Camera.from_json}
    checked = 0
    for path in sorted((CORPUS / "cases").glob("*/*.json")) + sorted((CORPUS / "good").glob("*.json")):
        kind = next((k for k in loaders if path.stem.startswith(k)), None)
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError, RecursionError):
            continue   # not JSON at all: no schema question
        if kind is None or not errors(validators[kind], doc):
            continue
        checked += 1
        with pytest.raises(FormatError):
            loaders[kind](doc, str(path))
    assert checked >= 10


def test_the_fuzz_corpus_good_documents_validate(validators):
    for kind in ("scene", "plan", "camera"):
        doc = json.loads((CORPUS / "good" / f"{kind}.json").read_text())
        assert errors(validators[kind], doc) == [], kind
