"""Install footprint of the core and of each extra, `make run` on a fresh clone, and the time
from `git clone` to a plan.

Each variant is a fresh venv (python -m venv, pip upgraded as a new user would not: left as it
comes) into which the wheel built from this checkout is installed with one extra; its size is
`du -s` of the venv, measured and then the venv deleted (the `train` one is ~6 GB). `--make-run`
clones HEAD, runs what `make run` installs (`make .venv/.installed-run`: `pip install -c
constraints.txt -e '.[console]'`), measures `.venv`, then starts `make run`, waits for the
console's URL and its first capture, fetches the page, reads which segmenter perceived that
capture from the session database, and stops the console (SIGTERM). The clone measurement
clones this repository (local `git clone`), creates a venv, installs the core and runs
`shelfpick plan` on a demo shelf, timing each step. pip's download cache is whatever the machine
has: say so when reporting (a cold cache adds the downloads).

    nice -n 10 python benchmarks/install_footprint.py --out docs/results/install-footprint.md
    nice -n 10 python benchmarks/install_footprint.py --extras core,perception   # a subset
    nice -n 10 python benchmarks/install_footprint.py --extras '' --no-clone --make-run   # make run only
    # the train extra on a CPU-only torch wheel installed first (pip takes it as torch==X)
    nice -n 10 python benchmarks/install_footprint.py --extras train --no-clone \
        --pre-install /opt/wheels/torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = ("core", "perception", "bench", "console", "distributed", "realsense", "train", "all")


def sh(cmd: list[str], cwd: Path | None = None) -> float:
    """Run, raise with its stderr on failure; wall seconds."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {proc.stderr.strip()[-2000:]}")
    return time.perf_counter() - t0


def du_mib(path: Path) -> float:
    out = subprocess.run(["du", "-sk", str(path)], capture_output=True, text=True, check=True).stdout
    return int(out.split()[0]) / 1024


def build_wheel(work: Path) -> Path:
    """From a clone of HEAD (setuptools builds in the source tree; the checkout stays clean)."""
    src = work / "src"
    sh(["git", "clone", "-q", str(ROOT), str(src)])
    sh([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q", "-w", str(work)])
    shutil.rmtree(src)
    return next(work.glob("shelfpick-*.whl"))


def footprint(wheel: Path, extra: str, work: Path, python: str, pre: list[str] = ()) -> dict:
    env = work / f"venv-{extra}"
    t_venv = sh([python, "-m", "venv", str(env)])
    empty = du_mib(env)
    if pre:
        t_venv += sh([str(env / "bin" / "python"), "-m", "pip", "install", "-q", *pre])
    spec = str(wheel) if extra == "core" else f"shelfpick[{extra}] @ {wheel.as_uri()}"
    t_install = sh([str(env / "bin" / "python"), "-m", "pip", "install", "-q", spec])
    size = du_mib(env)
    pkgs = subprocess.run([str(env / "bin" / "python"), "-m", "pip", "list", "--format=json"],
                          capture_output=True, text=True, check=True).stdout
    shutil.rmtree(env)
    return {"extra": extra + (f" (after {', '.join(Path(p).name for p in pre)})" if pre else ""), "venv_mib": round(size, 1), "empty_venv_mib": round(empty, 1),
            "added_mib": round(size - empty, 1), "packages": len(json.loads(pkgs)),
            "install_s": round(t_venv + t_install, 1)}


def clone_to_plan(work: Path, python: str) -> dict:
    """git clone -> venv -> pip install . (core) -> shelfpick plan on a demo shelf, timed."""
    repo = work / "clone"
    times = {"clone_s": sh(["git", "clone", "-q", str(ROOT), str(repo)])}
    times["venv_s"] = sh([python, "-m", "venv", str(repo / ".venv")])
    times["install_s"] = sh([str(repo / ".venv" / "bin" / "python"), "-m", "pip", "install", "-q", "."], repo)
    times["plan_s"] = sh([str(repo / ".venv" / "bin" / "shelfpick"), "plan", "static/demo/demo-small-6.json",
                          "--target", "b1", "--out", "plan.json"], repo)
    times["total_s"] = sum(times.values())
    shutil.rmtree(repo)
    return {k: round(v, 1) for k, v in times.items()}


def wait_for(proc: subprocess.Popen, log: Path, pattern: str, timeout: float) -> re.Match:
    """The first match of `pattern` in the growing `log` of `proc`; RuntimeError when it exits or times out."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = re.search(pattern, log.read_text(errors="replace"))
        if m:
            return m
        if proc.poll() is not None:
            break
        time.sleep(1)
    raise RuntimeError(f"make run: no {pattern!r} in {timeout:.0f} s: {log.read_text(errors='replace')[-1500:]}")


def make_run(work: Path, python: str) -> dict:
    """`make run` on a fresh clone: what it installs (size, time), then the console it starts."""
    repo = work / "make-run"
    sh(["git", "clone", "-q", str(ROOT), str(repo)])
    out = {"install_s": sh(["make", ".venv/.installed-run", f"PY={python}"], repo),
           "venv_mib": round(du_mib(repo / ".venv"), 1)}
    pkgs = json.loads(subprocess.run([str(repo / ".venv" / "bin" / "python"), "-m", "pip", "list", "--format=json"],
                                     capture_output=True, text=True, check=True).stdout)
    names = {p["name"].lower() for p in pkgs}
    out["packages"] = len(pkgs)
    out["torch_installed"] = "torch" in names
    out["onnxruntime_installed"] = "onnxruntime" in names
    log = repo / "make-run.log"
    t0 = time.perf_counter()
    with open(log, "w") as f:
        proc = subprocess.Popen(["make", "run"], cwd=repo, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = wait_for(proc, log, r"shelfpick console: (http://\S+)", 300).group(1)
        out["url_s"] = time.perf_counter() - t0
        wait_for(proc, log, r"first capture: .*", 300)
        out["first_capture_s"] = time.perf_counter() - t0
        with urllib.request.urlopen(url, timeout=30) as r:
            out["page_status"], out["page_bytes"] = r.status, len(r.read())
        db = sqlite3.connect(f"file:{repo / 'data' / 'shelfpick.db'}?mode=ro", uri=True)
        text = " ".join(doc for (doc,) in db.execute("select scene from scenes where kind = 'perceived'"))
        db.close()
        out["segmenters"] = sorted(set(re.findall(r'"segmenter": "(\w+)"', text)))
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
    shutil.rmtree(repo)
    return {k: round(v, 1) if isinstance(v, float) else v for k, v in out.items()}


def markdown(rows: list[dict], clone: dict | None, cmd: str, run: dict | None = None) -> str:
    lines = ["# Install footprint", "", f"`{cmd}` (Python {sys.version.split()[0]}, "
             f"{time.strftime('%Y-%m-%d')})", "",
             "| install | venv (MiB) | added to an empty venv (MiB) | packages | install (s) |",
             "|---|---:|---:|---:|---:|"]
    for r in rows:
        base, _, note = r["extra"].partition(" ")
        name = "core (`pip install shelfpick`)" if base == "core" else f"`shelfpick[{base}]`"
        name += f" {note}" if note else ""
        lines.append(f"| {name} | {r['venv_mib']:.0f} | {r['added_mib']:.0f} | {r['packages']} | {r['install_s']:.0f} |")
    if run:
        lines += ["", f"`make run` on a fresh clone (`pip install -c constraints.txt -e '.[console]'`): `.venv` "
                  f"{run['venv_mib']:.0f} MiB, {run['packages']} packages (torch: "
                  f"{'yes' if run['torch_installed'] else 'no'}, onnxruntime: {'yes' if run['onnxruntime_installed'] else 'no'}), "
                  f"installed in {run['install_s']:.0f} s; the console's URL after {run['url_s']:.0f} s, its first "
                  f"capture after {run['first_capture_s']:.0f} s, perceived by the {', '.join(run['segmenters'])} "
                  f"segmenter; the page HTTP {run['page_status']} ({run['page_bytes']} bytes)."]
    if clone:
        lines += ["", "From `git clone` to a plan with the core install: " +
                  ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in clone.items())]
    return "\n".join(lines) + "\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--extras", default=",".join(EXTRAS), help=f"comma separated, of {', '.join(EXTRAS)}")
    p.add_argument("--python", default=sys.executable, help="interpreter for the venvs (default: this one)")
    p.add_argument("--no-clone", action="store_true", help="skip the git clone -> plan timing")
    p.add_argument("--make-run", action="store_true", help="also `make run` on a fresh clone (size, console start)")
    p.add_argument("--pre-install", action="append", default=[], metavar="REQ",
                   help="install this first in every venv (e.g. a CPU-only torch wheel); repeatable")
    p.add_argument("--out", help="also write the markdown table here (and .json beside it)")
    args = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="shelfpick-footprint-") as tmp:
        work = Path(tmp)
        extras = [e.strip() for e in args.extras.split(",") if e.strip()]
        wheel = build_wheel(work) if extras else None
        for extra in extras:
            try:
                rows.append(footprint(wheel, extra, work, args.python, args.pre_install))
            except RuntimeError as exc:
                rows.append({"extra": extra, "error": str(exc).splitlines()[-1][:300]})
                print(f"{extra}: {rows[-1]['error']}", file=sys.stderr)
                continue
            print(json.dumps(rows[-1]), flush=True)
        run = make_run(work, args.python) if args.make_run else None
        if run:
            print(json.dumps(run), flush=True)
        clone = None if args.no_clone else clone_to_plan(work, args.python)
    cmd = "python benchmarks/install_footprint.py " + " ".join(sys.argv[1:])
    md = markdown([r for r in rows if "error" not in r], clone, cmd.strip(), run)
    print(md)
    if args.out:
        Path(args.out).write_text(md, encoding="utf-8")
        Path(args.out).with_suffix(".json").write_text(json.dumps({"rows": rows, "clone_to_plan": clone,
                                                                   "make_run": run}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
