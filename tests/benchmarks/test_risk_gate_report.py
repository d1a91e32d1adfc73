"""The gate's figures from judge rows (benchmarks/risk_gate_report.py): AUC, calibration error,
and judge_report.py rows read as evaluate.py's."""
from __future__ import annotations

import pytest

import benchmarks.risk_gate_report as rgr
from benchmarks.risk_gate_report import as_evaluate_rows, auc, calibration_error, figures


def test_auc_and_calibration_error_on_rows_whose_answer_is_known():
    rows = [{"ok": True, "risk": 0.01, "declared_safe": True}, {"ok": True, "risk": 0.02, "declared_safe": True},
            {"ok": False, "risk": 0.9, "declared_safe": False}, {"ok": False, "risk": 0.02, "declared_safe": False}]
    assert auc(rows) == pytest.approx((1 + 1 + 0.5 + 1) / 4)
    ece, table = calibration_error(rows)
    # bin [0, 0.1): risks 0.01, 0.02, 0.02 (mean 0.0167) and one failure in three; bin [0.9, 1.0): 0.9, failed
    assert ece == pytest.approx(3 / 4 * abs(0.05 / 3 - 1 / 3) + 1 / 4 * abs(0.9 - 1.0))
    assert [t["plans"] for t in table] == [3, 1]
    f = figures(rows)
    assert (f["ok"], f["held_declared_safe"], f["declared_safe"], f["safe_collapsed"]) == (2, 2, 2, 0)


def test_judge_report_rows_read_per_engine():
    rows = [{"scene": "s00", "target": "b1", "declared_safe": True, "success_prob": 0.97,
             "judges": {"pybullet": {"ok": True}, "mujoco": {"ok": False}}}]
    pb, mj = as_evaluate_rows(rows, "pybullet")[0], as_evaluate_rows(rows, "mujoco")[0]
    assert pb["ok"] and not mj["ok"] and pb["risk"] == pytest.approx(0.03) and pb["declared_safe"]


def test_a_run_without_label_or_file_is_one_line_and_exit_2(tmp_path, capsys):
    assert rgr.main([str(tmp_path / "rows.jsonl")]) == 2
    assert "expected LABEL=ROWS.jsonl" in capsys.readouterr().err
    assert rgr.main([f"a={tmp_path / 'missing.jsonl'}"]) == 2
    err = capsys.readouterr().err
    assert "cannot read judge rows" in err and len(err.strip().splitlines()) == 1
    bad = tmp_path / "bad.jsonl"
    bad.write_text("{not json\n")
    assert rgr.main([f"a={bad}"]) == 2
