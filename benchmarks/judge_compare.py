"""Is a change a gain, or the luck of the draws? Judge rows of two variants over several seeds.

A plan's verdict on the judge flips for some marginal tasks whenever the sample worlds are
drawn again, so a difference of a few tasks between two single runs says little. This
script reads `judge_report.py` rows (one file per plan seed, made with `--seed`) of a
baseline A and a variant B, and prints, per noise level and engine:

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
import json
import sys
from pathlib import Path
from typing import Sequence

ENGINES = ("pybullet", "mujoco")


class UsageError(ValueError):
    """A bad argument or rows file, told in one line."""


def read(path: str) -> dict[str, dict]:
    """The rows of one judge_report file by key (noise|planner|task)."""
    rows: dict[str, dict] = {}
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror})") from None
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            rows[row["key"]] = row
        except (ValueError, KeyError, TypeError):
            raise UsageError(f"{path}: line {n}: not a judge_report row") from None
    return rows


def _held(row: dict, engine: str) -> bool | None:
    j = row.get("judges", {}).get(engine)
    return None if j is None else bool(j.get("ok"))


def figures(rows: dict[str, dict], noise: float, engine: str,
            keys: set[str] | None = None) -> tuple[int, int, int, int]:
    """(ok, tasks, declared safe that collapsed, declared safe) at one noise level and engine
    (over `keys` only, when given)."""
    at = [r for k, r in rows.items() if (keys is None or k in keys)
          and r["noise"] == noise and _held(r, engine) is not None]
    safe = [r for r in at if r.get("declared_safe")]
    return (sum(1 for r in at if _held(r, engine)), len(at),
            sum(1 for r in safe if not _held(r, engine)), len(safe))


def flips(a: dict[str, dict], b: dict[str, dict], noise: float, engine: str) -> list[str]:
    """The tasks (keys present in both) whose verdict differs between two row sets."""
    return sorted(k for k in a.keys() & b.keys()
                  if a[k]["noise"] == noise and _held(a[k], engine) is not None
                  and _held(a[k], engine) != _held(b[k], engine))


def seed_noise(runs: Sequence[dict[str, dict]], noise: float, engine: str) -> float | None:
    """Mean number of verdicts that differ between two seeds of the same code (None: one seed)."""
    pairs = list(itertools.combinations(runs, 2))
    return sum(len(flips(x, y, noise, engine)) for x, y in pairs) / len(pairs) if pairs else None


def steady_changes(a_runs: Sequence[dict[str, dict]], b_runs: Sequence[dict[str, dict]], noise: float,
                   engine: str) -> tuple[list[str], list[str]]:
    """(gained, lost): tasks that B holds in every seed and A in none, and the reverse."""
    keys = set.intersection(*(set(r) for r in list(a_runs) + list(b_runs)))
    keys = {k for k in keys if a_runs[0][k]["noise"] == noise}

    def every(runs, k, want):
        return all(_held(r[k], engine) is want for r in runs)
    gained = sorted(k for k in keys if every(b_runs, k, True) and every(a_runs, k, False))
    lost = sorted(k for k in keys if every(b_runs, k, False) and every(a_runs, k, True))
    return gained, lost


def compare(a_runs: Sequence[dict[str, dict]], b_runs: Sequence[dict[str, dict]]) -> list[dict]:
    """One record per (noise, engine) that both variants have."""
    # only the tasks every file has: a run still going (or cut short) compares on what it did
    common = set.intersection(*(set(r) for r in list(a_runs) + list(b_runs)))
    noises = sorted({run[k]["noise"] for run in a_runs for k in common})
    out = []
    for noise in noises:
        for engine in ENGINES:
            fa = [figures(r, noise, engine, common) for r in a_runs]
            fb = [figures(r, noise, engine, common) for r in b_runs]
            if not any(f[1] for f in fa) or not any(f[1] for f in fb):
                continue
            gained, lost = steady_changes(a_runs, b_runs, noise, engine)
            out.append({"noise": noise, "engine": engine, "a": fa, "b": fb,
                        "a_mean": sum(f[0] for f in fa) / len(fa), "b_mean": sum(f[0] for f in fb) / len(fb),
                        "a_seed_noise": seed_noise(a_runs, noise, engine),
                        "b_seed_noise": seed_noise(b_runs, noise, engine),
                        "gained": gained, "lost": lost})
    return out


def to_markdown(records: Sequence[dict], a_names: Sequence[str], b_names: Sequence[str]) -> str:
    def runs(fs):
        return ", ".join(f"{ok}/{n} ({c}/{s})" for ok, n, c, s in fs)

    def noise_txt(x):
        return "-" if x is None else f"{x:.1f}"
    lines = [f"A: {', '.join(a_names)}", f"B: {', '.join(b_names)}", "",
             "| noise | engine | A ok per seed (declared safe collapsed) | B ok per seed | A mean | B mean "
             "| B - A | verdicts that differ between seeds: A / B | B gains in every seed | B loses in every seed |",
             "|---|---|---|---|---:|---:|---:|---|---|---|"]
    for r in records:
        lines.append(f"| {r['noise']:g} | {r['engine']} | {runs(r['a'])} | {runs(r['b'])} | {r['a_mean']:.1f} "
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
