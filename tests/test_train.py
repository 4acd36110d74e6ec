"""train.py end to end (quick profile, C backend) and its argument checks."""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
import train  # noqa: E402


def test_train_quick_writes_report_and_metrics(tmp_path):
    assert train.main(["--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "env_check.json").read_text())
    rows = {(r["action"], r["position"]): r for r in data["scripted_episodes"]}
    assert len(rows) == 6
    for pos in ("left", "middle", "right"):
        assert rows["point", pos]["final_point_l1"] < 0.01
        assert rows["push", pos]["target_moved_m"] > 0.02
        assert rows["push", pos]["others_moved_m"] < 1e-3
    report = (tmp_path / "REPORT.md").read_text()
    assert "skipped: not built yet" in report and "| push | left |" in report
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize("argv, field", [(["--profile", "huge"], "--profile"),
                                         (["--backend", "ode"], "--backend")])
def test_train_rejects_bad_arguments(argv, field, capsys):
    with pytest.raises(SystemExit):
        train.parse_args(argv)
    assert field in capsys.readouterr().err
