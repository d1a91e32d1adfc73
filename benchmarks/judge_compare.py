"""Is a change a gain, or the luck of the draws? Judge rows of two variants over several seeds.

A plan's verdict on the judge flips for some marginal tasks whenever the sample worlds are
drawn again, so a difference of a few tasks between two single runs says little. This
script reads `judge_report.py` rows (one file per plan seed, made with `--seed`) of a
baseline A and a variant B, and prints, per noise level, planner and engine:

- ok (and declared safe that collapsed) per seed, and the mean over the seeds;
- the seed noise: how many task verdicts differ between two seeds of the same code
  (mean over the pairs of seeds within A, and within B);
- the change: mean ok of B minus mean ok of A, and the tasks whose verdict B changed in
  every seed (the changes that are not the draws').

Only the tasks that every file holds are counted, so a run still going compares on what it did.

    .venv/bin/python benchmarks/judge_compare.py --a base-s0.jsonl,base-s1.jsonl \\
        --b new-s0.jsonl,new-s1.jsonl [--out compare.md]

Exit 2 (and a one-line error) on a missing or unreadable rows file.
"""
from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import read_rows  # noqa: E402
from benchmarks.judge_summary import ENGINES, engine_summary  # noqa: E402

Run = dict[str, dict]   # one rows file: key (noise|planner|task) -> row


class UsageError(ValueError):
    """A bad argument or rows file, told in one line."""


def read(path: str) -> Run:
    """The rows of one judge_report file by key (`judge_rows.read_rows`: a torn last line of a run
    still going is dropped)."""
    if not Path(path).is_file():
        raise UsageError(f"{path}: no such rows file")
    rows = {r["key"]: r for r in read_rows(Path(path))}
    if not rows:
        raise UsageError(f"{path}: no judge_report rows in it")
    return rows


def _held(row: dict, engine: str) -> bool:
    return bool(row.get("judges", {}).get(engine, {}).get("ok"))


def figures(run: Run, engine: str) -> tuple[int, int, int, int]:
    """(ok, tasks, declared safe that collapsed, declared safe): `engine_summary`'s figures."""
    s = engine_summary(list(run.values()), engine)
    return s["ok"], s["tasks"], s["declared_safe_collapsed"], s["declared_safe"]


def flips(a: Run, b: Run, engine: str) -> int:
    """How many tasks have another verdict in `b` than in `a` (the same keys)."""
    return sum(1 for k in a if _held(a[k], engine) != _held(b[k], engine))


def seed_noise(runs: Sequence[Run], engine: str) -> float | None:
    """Mean number of verdicts that differ between two seeds of the same code (None: one seed)."""
    pairs = list(itertools.combinations(runs, 2))
    return sum(flips(x, y, engine) for x, y in pairs) / len(pairs) if pairs else None


def steady_changes(a_runs: Sequence[Run], b_runs: Sequence[Run], engine: str) -> tuple[list[str], list[str]]:
    """(gained, lost): tasks that B holds in every seed and A in none, and the reverse."""
    def every(runs, k, want):
        return all(_held(r[k], engine) is want for r in runs)
    keys = sorted(a_runs[0])
    return ([k for k in keys if every(b_runs, k, True) and every(a_runs, k, False)],
            [k for k in keys if every(b_runs, k, False) and every(a_runs, k, True)])


def compare(a_runs: Sequence[Run], b_runs: Sequence[Run]) -> list[dict]:
    """One record per (noise, planner, engine) that the rows hold, over the tasks every file has
    (a run still going, or cut short, compares on what it did)."""
    common = set.intersection(*(set(r) for r in list(a_runs) + list(b_runs)))
    first = a_runs[0]
    out = []
    for noise, planner in sorted({(first[k]["noise"], first[k]["planner"]) for k in common}):
        keys = {k for k in common if (first[k]["noise"], first[k]["planner"]) == (noise, planner)}
        a = [{k: r[k] for k in keys} for r in a_runs]
        b = [{k: r[k] for k in keys} for r in b_runs]
        for engine in ENGINES:
            if not any(engine in r.get("judges", {}) for r in a[0].values()):
                continue
            gained, lost = steady_changes(a, b, engine)
            fa, fb = [figures(r, engine) for r in a], [figures(r, engine) for r in b]
            out.append({"noise": noise, "planner": planner, "engine": engine, "a": fa, "b": fb,
                        "a_mean": sum(f[0] for f in fa) / len(fa), "b_mean": sum(f[0] for f in fb) / len(fb),
                        "a_seed_noise": seed_noise(a, engine), "b_seed_noise": seed_noise(b, engine),
                        "gained": gained, "lost": lost})
    return out


def to_markdown(records: Sequence[dict], a_names: Sequence[str], b_names: Sequence[str]) -> str:
    def runs(fs):
        return ", ".join(f"{ok}/{n} ({c}/{s})" for ok, n, c, s in fs)

    def noise_txt(x):
        return "-" if x is None else f"{x:.1f}"
    lines = [f"A: {', '.join(a_names)}", f"B: {', '.join(b_names)}", "",
             "| noise | planner | engine | A ok per seed (declared safe collapsed) | B ok per seed | A mean | B mean "
             "| B - A | verdicts that differ between seeds: A / B | B gains in every seed | B loses in every seed |",
             "|---|---|---|---|---|---:|---:|---:|---|---|---|"]
    for r in records:
        lines.append(f"| {r['noise']:g} | {r['planner']} | {r['engine']} | {runs(r['a'])} | {runs(r['b'])} | {r['a_mean']:.1f} "
                     f"| {r['b_mean']:.1f} | {r['b_mean'] - r['a_mean']:+.1f} | {noise_txt(r['a_seed_noise'])} / "
                     f"{noise_txt(r['b_seed_noise'])} | {' '.join(r['gained']) or '-'} | {' '.join(r['lost']) or '-'} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", required=True, help="comma list of the baseline's rows files (one per seed)")
    ap.add_argument("--b", required=True, help="comma list of the variant's rows files (one per seed)")
    ap.add_argument("--out", default=None, help="also write the table here (markdown)")
    args = ap.parse_args(argv)
    a_names = [p for p in args.a.split(",") if p.strip()]
    b_names = [p for p in args.b.split(",") if p.strip()]
    try:
        if not a_names or not b_names:
            raise UsageError("--a and --b each need at least one rows file")
        records = compare([read(p) for p in a_names], [read(p) for p in b_names])
    except UsageError as exc:
        print(f"judge_compare: {exc}", file=sys.stderr)
        return 2
    text = to_markdown(records, a_names, b_names)
    print(text, end="")
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
