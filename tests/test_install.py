"""The wheel installs on its own: built from this checkout, installed into a clean venv (core
dependencies only, numpy and pybullet, from the package index), it plans and simulates from the
demo shelves it carries, and a command that needs an extra says which in one line. `make run` on
a copy of the checkout installs the console without torch and starts it.

Slow (venvs and up to ~900 MB of wheels: 20-90 s a test with pip's cache warm); `make test-all` runs them.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import urllib.request
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def source_copy(dest: Path) -> Path:
    """The checkout's files as git sees them (tracked and new, not ignored): setuptools builds in
    the source tree (build/), which must neither litter the checkout nor carry stale modules."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.splitlines()
    for name in files:
        src = ROOT / name
        if src.is_file() and not name.startswith(("tests/", "benchmarks/")):
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    src = source_copy(tmp_path_factory.mktemp("src"))
    proc = run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q", "-w", str(out)], ROOT)
    assert proc.returncode == 0, proc.stderr
    (whl,) = out.glob("shelfpick-*.whl")
    return whl


def test_the_wheel_carries_weights_demo_shelves_and_the_license(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"shelfpick/static/weights/shelfpick-seg.pt", "shelfpick/static/weights/shelfpick-learned.onnx",
            "shelfpick/static/weights/shelfpick-learned-photo.onnx"} <= names
    assert {f"shelfpick/static/demo/{p.name}" for p in (ROOT / "static" / "demo").glob("*.json")} <= names
    assert any(n.endswith("licenses/LICENSE") for n in names)
    assert not any(n.startswith(("tests/", "benchmarks/")) for n in names)


def test_core_install_plans_and_simulates_from_a_clean_venv(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    proc = run([str(py), "-m", "pip", "install", "-q", str(wheel)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    freeze = run([str(py), "-m", "pip", "freeze"], tmp_path).stdout.lower()
    assert "torch" not in freeze and "viser" not in freeze and "opencv" not in freeze
    exe = str(env_dir / "bin" / "shelfpick")
    site = run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path).stdout.strip()
    demo = Path(site) / "shelfpick" / "static" / "demo" / "demo-small-6.json"   # the demo shelf from the wheel
    assert demo.is_file()
    # run outside the checkout, so nothing is imported from it
    plan = run([exe, "plan", str(demo), "--target", "b1", "--out", str(tmp_path / "plan.json")], tmp_path)
    assert plan.returncode == 0, plan.stderr
    doc = json.loads((tmp_path / "plan.json").read_text())
    assert doc["sequence"][-1] == "b1" and doc["provenance"]["shelfpick_version"] != "unknown"
    sim = run([exe, "simulate", str(demo), str(tmp_path / "plan.json")], tmp_path)
    assert sim.returncode in (0, 3) and json.loads(sim.stdout)["format"] == "shelfpick.verdict/1"
    perceive = run([exe, "perceive", "--rgb", "x.png", "--camera", "c.json", "--out", "s.json"], tmp_path)
    assert perceive.returncode == 2 and "shelfpick[perception]" in perceive.stderr
    assert len(perceive.stderr.strip().splitlines()) == 1
    version = run([exe, "--version"], tmp_path)
    assert version.stdout.strip() == f"shelfpick {doc['provenance']['shelfpick_version']}"


def test_the_yolo_segmenter_finds_its_weights_in_the_installed_wheel(wheel, tmp_path):
    """Issue 13: from the wheel, `perceive --segmenter yolo` said "weights not found". The wheel's
    files (pip install --target, no dependencies) run here on this venv's torch and ultralytics."""
    pytest.importorskip("ultralytics")
    site = tmp_path / "site"
    proc = run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    env = {**os.environ, "PYTHONPATH": str(site)}
    code = "import shelfpick.perception.segment as s; print(s.__file__); print(s.DEFAULT_WEIGHTS)"
    where = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    module, weights = where.stdout.split()
    assert module.startswith(str(site)) and weights.startswith(str(site)) and Path(weights).is_file()
    cli = [sys.executable, "-c", "import sys; from shelfpick.console.cli import main; sys.exit(main())"]
    demo = site / "shelfpick" / "static" / "demo" / "demo-small-6.json"
    assert subprocess.run(cli + ["render", str(demo), "--out", "cap"], cwd=tmp_path, env=env).returncode == 0
    perceive = subprocess.run(cli + ["perceive", "--rgb", "cap/rgb.png", "--depth", "cap/depth.png", "--camera",
                                     "cap/camera.json", "--segmenter", "yolo", "--out", "scene.json"],
                              cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert perceive.returncode == 0, perceive.stderr
    assert "(yolo" in perceive.stderr and json.loads((tmp_path / "scene.json").read_text())["boxes"]


def test_perception_extra_renders_and_perceives_from_a_clean_venv(wheel, tmp_path):
    """`pip install 'shelfpick[perception]'` (opencv, scipy, pillow, tqdm, onnxruntime; ~850 MB): the
    default segmenter, the learned one on ONNX Runtime, runs without torch on a render of the wheel's
    demo shelf, and plans on the result; `--segmenter yolo` names the `train` extra in one line."""
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    proc = run([str(py), "-m", "pip", "install", "-q", f"shelfpick[perception] @ {wheel.as_uri()}"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    freeze = run([str(py), "-m", "pip", "freeze"], tmp_path).stdout.lower()
    assert "torch" not in freeze and "onnxruntime" in freeze
    exe = str(env_dir / "bin" / "shelfpick")
    site = run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path).stdout.strip()
    demo = str(Path(site) / "shelfpick" / "static" / "demo" / "demo-small-6.json")
    render = run([exe, "render", demo, "--out", "cap"], tmp_path)
    assert render.returncode == 0 and render.stdout == "", render.stderr
    perceive = run([exe, "perceive", "--rgb", "cap/rgb.png", "--depth", "cap/depth.png", "--camera",
                    "cap/camera.json", "--out", "scene.json"], tmp_path)
    assert perceive.returncode == 0, perceive.stderr
    scene = json.loads((tmp_path / "scene.json").read_text())
    assert len(scene["boxes"]) == 6 and scene["source"]["segmenter"] == "learned"
    yolo = run([exe, "perceive", "--rgb", "cap/rgb.png", "--depth", "cap/depth.png", "--camera", "cap/camera.json",
                "--segmenter", "yolo", "--out", "y.json"], tmp_path)
    assert yolo.returncode == 2 and "shelfpick[train]" in yolo.stderr and len(yolo.stderr.strip().splitlines()) == 1
    plan = run([exe, "plan", "scene.json", "--task", "clear", "--planner", "heuristic"], tmp_path)
    assert plan.returncode == 0 and json.loads(plan.stdout)["task"] == "clear", plan.stderr


def _wait_for(proc: subprocess.Popen, log: Path, pattern: str, timeout: float) -> re.Match:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = re.search(pattern, log.read_text(errors="replace"))
        if m or proc.poll() is not None:
            break
        time.sleep(1)
    assert m, log.read_text(errors="replace")[-2000:]
    return m


def test_make_run_installs_the_console_without_torch_and_starts_it(tmp_path):
    """Issue 34: `make run` on a fresh copy of the checkout installs `.[console]` only (no torch,
    `.venv` <= 1.5 GB; it was 7.0 GB), starts the console on the demo shelf, whose first capture
    the learned segmenter perceives (on ONNX Runtime), serves its page, and stops on SIGTERM."""
    repo = source_copy(tmp_path / "repo")
    python = f"python{sys.version_info.major}.{sys.version_info.minor}"
    proc = run(["make", ".venv/.installed-run", f"PY={shutil.which(python) or sys.executable}"], repo, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    size = int(subprocess.run(["du", "-sk", str(repo / ".venv")], capture_output=True, text=True).stdout.split()[0])
    assert size <= 1.5 * 2**20, f".venv is {size / 2**20:.2f} GiB"
    freeze = run([str(repo / ".venv" / "bin" / "python"), "-m", "pip", "freeze"], repo).stdout.lower()
    assert "torch" not in freeze and "ultralytics" not in freeze and "onnxruntime" in freeze
    assert not (repo / ".venv" / ".installed").exists()        # the full install is make test's
    log = tmp_path / "run.log"
    with open(log, "w") as f:
        console = subprocess.Popen(["make", "run"], cwd=repo, stdout=f, stderr=subprocess.STDOUT,
                                   start_new_session=True)
    try:
        url = _wait_for(console, log, r"shelfpick console: (http://\S+)", 300).group(1)
        _wait_for(console, log, r"first capture: captured demo", 300)
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read(4096).lower()
        db = sqlite3.connect(f"file:{repo / 'data' / 'shelfpick.db'}?mode=ro", uri=True)
        sources = [json.loads(doc).get("source", {}) for (doc,) in db.execute("select scene from scenes where kind = 'perceived'")]
        db.close()
        assert sources and all(s.get("segmenter") == "learned" for s in sources), sources
    finally:
        os.killpg(console.pid, signal.SIGTERM)
        console.wait(timeout=60)
    assert "stopped by SIGTERM" in log.read_text()



def test_the_wheel_installs_one_import_package_beside_pypis_console(wheel, tmp_path):
    """Issue 34: the wheel put console/, planning/, perception/, static/ and robotsim/ at the top of
    site-packages, and PyPI's `console` (an ANSI terminal library) overwrote ours or ours it. Now the
    wheel holds one import package, `shelfpick`, and both install and import side by side."""
    tops = {n.split("/", 1)[0] for n in zipfile.ZipFile(wheel).namelist()}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"shelfpick"}
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = str(env_dir / "bin" / "python")
    proc = run([py, "-m", "pip", "install", "-q", str(wheel), "console"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    code = ("import console, shelfpick.console.cli, shelfpick.planning.planner as p; "
            "print(console.__file__); print(p.__file__)")
    out = run([py, "-c", code], tmp_path)
    assert out.returncode == 0, out.stderr
    theirs, ours = out.stdout.split()
    assert "/shelfpick/" not in theirs and theirs.endswith("console/__init__.py")
    assert ours.endswith("shelfpick/planning/planner.py")
    assert run([str(env_dir / "bin" / "shelfpick"), "--version"], tmp_path).returncode == 0
