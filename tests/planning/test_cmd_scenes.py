"""`shelfpick scenes` writes seeded, loadable scene files; bad arguments exit 2 with one line."""
from __future__ import annotations

from pathlib import Path

from shelfpick.console.cli import main
from shelfpick.perception.scene import Scene


def test_scenes_cli_writes_seeded_files(tmp_path: Path) -> None:
    out = tmp_path / "s"
    assert main(["scenes", "--kind", "unstructured", "--count", "2", "--seed", "4", "--out", str(out),
                 "--boxes", "6-7"]) == 0
    files = sorted(out.glob("*.json"))
    assert [f.name for f in files] == ["unstructured-4-0000.json", "unstructured-4-0001.json"]
    scenes = [Scene.load(f) for f in files]
    assert all(6 <= len(s.boxes) <= 7 for s in scenes)
    assert all(s.source["kind"] == "unstructured" for s in scenes)
    again = tmp_path / "t"
    assert main(["scenes", "--kind", "unstructured", "--count", "1", "--seed", "4", "--out", str(again),
                 "--boxes", "6-7"]) == 0
    assert (again / "unstructured-4-0000.json").read_text() == files[0].read_text()


def test_scenes_cli_bad_arguments(tmp_path: Path, capsys) -> None:
    assert main(["scenes", "--kind", "structured", "--count", "1", "--out", str(tmp_path), "--boxes", "9-x"]) == 2
    assert "--boxes" in capsys.readouterr().err
    assert main(["scenes", "--kind", "structured", "--count", "0", "--out", str(tmp_path)]) == 2
    assert "--count" in capsys.readouterr().err


def test_demo_shelves_load() -> None:
    demo = Path(__file__).resolve().parents[2] / "static" / "demo"
    files = sorted(demo.glob("*.json"))
    assert len(files) >= 3
    for f in files:
        s = Scene.load(f)
        assert 5 <= len(s.boxes) <= 14


def test_scenes_cli_hard_kind_has_masses_and_can_drop_them(tmp_path: Path) -> None:
    assert main(["scenes", "--kind", "proud", "--count", "1", "--seed", "2", "--out", str(tmp_path / "a"),
                 "--boxes", "8"]) == 0
    scene = Scene.load(tmp_path / "a" / "proud-2-0000.json")
    assert scene.source["kind"] == "proud" and len(scene.boxes) == 8
    assert all(0.3 <= b.mass <= 5.0 for b in scene.boxes)
    assert main(["scenes", "--kind", "proud", "--count", "1", "--seed", "2", "--out", str(tmp_path / "b"),
                 "--boxes", "8", "--no-masses"]) == 0
    assert all(b.mass is None for b in Scene.load(tmp_path / "b" / "proud-2-0000.json").boxes)
    assert main(["scenes", "--kind", "structured", "--count", "1", "--seed", "2", "--out", str(tmp_path / "c"),
                 "--boxes", "8", "--masses"]) == 0
    assert all(b.mass is not None for b in Scene.load(tmp_path / "c" / "structured-2-0000.json").boxes)


def test_scenes_cli_unknown_kind(tmp_path: Path, capsys) -> None:
    import pytest

    with pytest.raises(SystemExit) as exc:
        main(["scenes", "--kind", "tower", "--count", "1", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "tower" in capsys.readouterr().err
