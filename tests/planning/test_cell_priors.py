"""`shelfpick plan --cell cell.toml`: the cell's [planning] section gives the sample worlds' masses,
friction and pull modes and the plan threshold's default, checked by the one check the console
makes too (planning.priors.section_kwargs); a wrong cell is one line naming file and field, exit 2."""
from __future__ import annotations

import json
import textwrap

import pytest

from shelfpick.console.cell import CellError, read_cell
from shelfpick.console.cli import main
from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.calibration import calibration_for
from shelfpick.planning.priors import CellPriors

# the console's sections are the console's: `plan` reads [planning] only
CELL = """
format = "shelfpick.cell/1"

[robot]
url = "sim"

[safety]
samples = 4

[planning]
mass_kg = [0.5, 3]
pull_modes = ["drag"]
max_plan_risk = 0.2
"""


def _scene(tmp_path):
    """A box on a box, depths unseen (the worlds draw them), masses unknown (the worlds draw them)."""
    box = lambda bid, z: Box(bid, (0.2, 0.2, 0.2), (-0.3, 0.15, z), (1.0, 0.0, 0.0, 0.0))   # noqa: E731
    path = tmp_path / "seen.json"
    Scene(Shelf(), (box("bot", 0.1), box("top", 0.3))).hide_depths().save(path)
    return str(path)


def _cell(tmp_path, text=CELL, name="cell.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


def _plan(tmp_path, *extra):
    out = tmp_path / "plan.json"
    argv = ["plan", _scene(tmp_path), "--target", "top", "--samples", "2", "--workers", "1", "--verify", "0",
            "--out", str(out), *extra]
    assert main(argv) == 0
    return json.loads(out.read_text())["search"]


def test_the_cells_masses_and_pull_modes_are_what_the_worlds_draw_and_gate_with(tmp_path, capsys):
    search = _plan(tmp_path, "--cell", _cell(tmp_path))
    model = search["uncertainty"]
    assert model["mass_kg"] == [0.5, 3.0] and model["pull_modes"] == ["drag"]
    assert model["friction"] == [0.6, 0.9]                  # what the cell leaves out stays the default
    gate = search["plan_risk"]                              # a gripper that only drags: the drag map
    drag = calibration_for(("drag",)).probability(gate["failed_worlds"], gate["worlds"])
    assert gate["probability"] == pytest.approx(drag, abs=1e-4)
    assert drag != pytest.approx(calibration_for(("lift", "drag")).probability(gate["failed_worlds"], gate["worlds"]))
    plain = _plan(tmp_path)["uncertainty"]                  # without --cell: the defaults
    assert plain["mass_kg"] == [0.3, 5.0] and plain["pull_modes"] == ["lift", "drag"]
    capsys.readouterr()


def test_the_cell_combines_with_face_error_and_no_catalogue(tmp_path, capsys):
    model = _plan(tmp_path, "--cell", _cell(tmp_path), "--face-error", "0.01", "--no-catalogue")["uncertainty"]
    assert model["mass_kg"] == [0.5, 3.0] and model["pull_modes"] == ["drag"]
    assert (model["face_error_m"], model["face_size_error_m"], model["face_depth_error_m"]) == (0.01, 0.01, 0.01)
    assert model["catalogue"] == []
    capsys.readouterr()


def test_the_cells_plan_threshold_is_the_default_and_the_flag_wins(tmp_path, capsys):
    cell = _cell(tmp_path)
    assert _plan(tmp_path, "--cell", cell)["max_plan_risk"] == 0.2
    explicit = _plan(tmp_path, "--cell", cell, "--max-plan-risk", "0.3")
    assert explicit["max_plan_risk"] == 0.3 and explicit["plan_risk"]["max_plan_risk"] == 0.3
    no_threshold = _cell(tmp_path, CELL.replace("max_plan_risk = 0.2\n", ""), "other.toml")
    assert _plan(tmp_path, "--cell", no_threshold)["max_plan_risk"] == CellPriors().max_plan_risk
    capsys.readouterr()


BAD = [
    ("mass_kg = [0.5, 3]", "mass_kg = [3, 1]", "planning.mass_kg", "[3, 1]"),
    ('pull_modes = ["drag"]', 'pull_modes = ["fly"]', "planning.pull_modes", "'fly'"),
    ('pull_modes = ["drag"]', 'pull_modes = ["drag", "drag"]', "planning.pull_modes", "['drag', 'drag']"),
    ("max_plan_risk = 0.2", "max_plan_risk = 0", "planning.max_plan_risk", "got 0"),
    ("max_plan_risk = 0.2", "max_risk = 0.2", "planning.max_risk", "unknown key"),
    ("[planning]", "[planning]\nfriction = [0.6, true]", "planning.friction", "True"),
]


@pytest.mark.parametrize("old, new, field, value", BAD)
def test_a_wrong_planning_value_is_one_line_and_the_console_says_the_same(tmp_path, capsys, old, new, field, value):
    path = _cell(tmp_path, CELL.replace(old, new))
    assert main(["plan", _scene(tmp_path), "--target", "top", "--cell", path]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and path in err[0] and field in err[0] and value in err[0], err
    with pytest.raises(CellError) as console:      # the console's reading of the same file: the same line
        read_cell(path)
    assert err[0].endswith(str(console.value))


@pytest.mark.parametrize("text, what", [
    ('{"format": "shelfpick.scene/1"}', "not valid TOML"),
    ("[planning\nmass_kg = [1, 2]\n", "not valid TOML"),
    ('format = "shelfpick.plan/1"\n', "format: expected 'shelfpick.cell/1'"),
    ("planning = 3\n", "planning: expected a table"),
    (None, "cell file not found"),
    ("", "not a regular file"),
])
def test_a_cell_file_that_cannot_be_read_is_one_line_naming_it(tmp_path, capsys, text, what):
    path = tmp_path / "cell.toml"
    if text == "":
        path.mkdir()
    elif text is not None:
        path.write_text(text)
    assert main(["plan", _scene(tmp_path), "--target", "top", "--cell", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and what in err[0] and "Traceback" not in err[0], err


def test_the_section_check_is_a_format_error_naming_the_origin():
    assert CellPriors.from_section({"mass_kg": [1, 2], "pull_modes": ["lift"]}, "c.toml") == \
        CellPriors(mass=(1.0, 2.0), pull_modes=("lift",))
    assert CellPriors.from_section({}, "c.toml") == CellPriors()
    with pytest.raises(FormatError) as err:
        CellPriors.from_section({"friction": [0.6, 3.0]}, "c.toml")
    assert str(err.value) == "c.toml: planning.friction: expected [low, high] with 0.01 <= low <= high <= 2, " \
                             "got [0.6, 3.0]"


def test_the_plan_records_which_cell_file_and_which_priors_made_it(tmp_path, capsys):
    def provenance(*extra):
        _plan(tmp_path, *extra)
        return json.loads((tmp_path / "plan.json").read_text())["provenance"]

    cell = _cell(tmp_path)
    got = provenance("--cell", cell)["cell"]
    assert got["path"] == cell and len(got["section_hash"]) == 16
    # the same [planning] in another layout: the same hash; another prior: another hash
    same = _cell(tmp_path, CELL.replace("[robot]\nurl = \"sim\"\n", "").replace("mass_kg = [0.5, 3]", "mass_kg = [ 0.5, 3 ]"),
                 "same.toml")
    assert provenance("--cell", same)["cell"]["section_hash"] == got["section_hash"]
    other = _cell(tmp_path, CELL.replace("mass_kg = [0.5, 3]", "mass_kg = [0.5, 4]"), "other.toml")
    assert provenance("--cell", other)["cell"]["section_hash"] != got["section_hash"]
    assert "cell" not in provenance()                        # no --cell, no record
    capsys.readouterr()
