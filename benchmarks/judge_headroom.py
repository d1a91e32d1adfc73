"""Where each of the judge's tasks stands: what our plan did against what any plan can do.

Reads our plans' verdicts (the rows `../shared/judge/evaluate.py` prints, one run per engine, or
`judge_report.py` rows, which carry both) and the rows of `judge_ceiling.py --mode sets` (one run
with the pybullet judge, one with `--engines pybullet,mujoco`), and sorts every task into one of:

- `ours, both engines`: our plan holds in pybullet and in MuJoCo;
- `ours, pybullet only`: our plan holds in pybullet only; `robust plan exists` when the
  both-engine search found a plan for it;
- `missed, robust plan exists` / `missed, pybullet-only plan exists`: our plan fails in pybullet
  where the search found a plan that holds (in both engines / in pybullet only);
- `no plan holds`: the pybullet search found none (the judge's unsolvable tasks among them).

A task that neither search row covers is `not searched`. Prints the counts (per kind and in all)
and, with `--png`, draws them as stacked bars.

    .venv/bin/python benchmarks/judge_headroom.py --ours-pybullet eval0.log --ours-mujoco evalm.log \\
        --sets-pybullet sets-fail0.jsonl --sets-both sets-both.jsonl --png headroom.png
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import UsageError  # noqa: E402

CLASSES = ("ours, both engines", "ours, pybullet only, robust plan exists", "ours, pybullet only",
           "missed, robust plan exists", "missed, pybullet-only plan exists", "no plan holds", "not searched")
COLOURS = ("#2e7d32", "#9ccc65", "#c5e1a5", "#ef6c00", "#ffcc80", "#9e9e9e", "#e0e0e0")


def _rows(path: str) -> list[dict]:
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror})") from None
    out = []
    for n, line in enumerate(lines, 1):
        if not line.startswith("{"):
            continue   # evaluate.py's other output (pybullet's banner, the summary lines)
        try:
            out.append(json.loads(line))
        except ValueError:
            raise UsageError(f"{path}: line {n} is not a JSON row") from None
    return out


def verdicts(path: str, engine: str) -> dict[str, tuple[bool, str]]:
    """task -> (ok in `engine`, kind) from evaluate.py rows or judge_report.py rows."""
    out = {}
    for r in _rows(path):
        if r.get("planner", "physics") != "physics" or "scene" not in r:
            continue
        ok = r["judges"].get(engine, {}).get("ok") if "judges" in r else r.get("ok")
        if ok is None:
            raise UsageError(f"{path}: row {r['scene']}:{r['target']} has no {engine} verdict")
        out[f"{r['scene']}:{r['target']}"] = (bool(ok), r.get("kind", ""))
    return out


def found(path: str) -> dict[str, bool]:
    """task -> whether `judge_ceiling.py --mode sets` found a plan that holds."""
    return {r["task"]: r["found"] is not None for r in _rows(path)}


def classify(py: dict[str, tuple[bool, str]], mj: dict[str, tuple[bool, str]], sets_py: dict[str, bool],
             sets_both: dict[str, bool]) -> dict[str, str]:
    """task -> its class (CLASSES). A task our plan holds in pybullet is holdable there."""
    out = {}
    for task, (ok, _) in py.items():
        both = mj.get(task, (False, ""))[0]
        if ok and both:
            out[task] = CLASSES[0]
        elif ok:
            out[task] = CLASSES[1] if sets_both.get(task) else CLASSES[2]
        elif sets_both.get(task):
            out[task] = CLASSES[3]
        elif task in sets_py:
            out[task] = CLASSES[4] if sets_py[task] else CLASSES[5]
        else:
            out[task] = CLASSES[6]
    return out


def counts(classes: dict[str, str], kinds: dict[str, str]) -> dict[str, dict[str, int]]:
    """{kind or "all": {class: tasks}}."""
    out: dict[str, dict[str, int]] = {}
    for task, c in classes.items():
        for k in (kinds.get(task) or "?", "all"):
            out.setdefault(k, dict.fromkeys(CLASSES, 0))[c] += 1
    return out


def plot(table: dict[str, dict[str, int]], path: Path) -> None:
    """Stacked horizontal bars, one per kind and one for all tasks."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = sorted(k for k in table if k != "all") + ["all"]
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.6 * len(kinds)))
    left = [0] * len(kinds)
    for c, colour in zip(CLASSES, COLOURS):
        widths = [table[k][c] for k in kinds]
        if not any(widths):
            continue
        ax.barh(kinds, widths, left=left, color=colour, label=c, edgecolor="white")
        for y, (x0, w) in enumerate(zip(left, widths)):
            if w:
                ax.text(x0 + w / 2, y, str(w), ha="center", va="center", fontsize=8)
        left = [a + b for a, b in zip(left, widths)]
    ax.set_xlabel("tasks")
    ax.set_title("the judge's tasks: our plan against what any plan can hold")
    ax.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.35 if len(kinds) < 4 else -0.2))
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ours-pybullet", required=True, help="our plans' rows judged by pybullet")
    ap.add_argument("--ours-mujoco", required=True, help="our plans' rows judged by MuJoCo (may be the same file)")
    ap.add_argument("--sets-pybullet", required=True, help="judge_ceiling.py --mode sets rows (pybullet)")
    ap.add_argument("--sets-both", required=True, help="judge_ceiling.py --mode sets --engines pybullet,mujoco rows")
    ap.add_argument("--png", default=None, help="write the stacked bars here")
    return ap.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    a = parse_args(argv)
    try:
        py = verdicts(a.ours_pybullet, "pybullet")
        mj = verdicts(a.ours_mujoco, "mujoco")
        classes = classify(py, mj, found(a.sets_pybullet), found(a.sets_both))
    except UsageError as exc:
        print(f"judge_headroom: {exc}", file=sys.stderr)
        return 2
    table = counts(classes, {t: k for t, (_, k) in py.items()})
    for kind, row in sorted(table.items(), key=lambda kv: kv[0] == "all"):
        print(f"{kind}: " + ", ".join(f"{c} {n}" for c, n in row.items() if n))

    def tasks_in(names: Sequence[str]) -> int:
        return sum(table["all"][c] for c in names)
    ours, missed = CLASSES[:3], CLASSES[3:5]
    robust = (CLASSES[0], CLASSES[1], CLASSES[3])
    unsearched = table["all"]["not searched"]
    print(f"ours hold in pybullet {tasks_in(ours)}/{len(classes)}; a plan holds in pybullet on "
          f"{tasks_in(ours + missed)}, in both engines on {tasks_in(robust)}"
          + (f"; {unsearched} not searched" if unsearched else ""))
    if a.png:
        plot(table, Path(a.png))
        print(f"wrote {a.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
