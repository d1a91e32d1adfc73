"""benchmarks/stand_unknowns.py: a shelf's draws counted under the default prior and its variants."""
import json

from benchmarks.stand_unknowns import main
from shelfpick.perception.scene import Box, Scene, Shelf


def test_a_standing_shelf_stands_under_every_prior_and_bad_input_exits_2(tmp_path, capsys):
    scene = Scene(Shelf(), (Box("a", (0.2, 0.25, 0.2), (0.0, 0.125, 0.1)),
                            Box("b", (0.2, 0.25, 0.2), (0.0, 0.125, 0.3)))).hide_depths()
    path = tmp_path / "two.json"
    path.write_text(json.dumps(scene.to_json()))
    assert main([str(path), "--draws", "2"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "prior" not in line]
    assert len(rows) == 5 and all(r.split(" | ")[1:3] == ["2", "2"] for r in rows), rows
    assert main([str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err
