"""The HTML report of ``bench compare`` shows the control charts of the check standards its
actual run relied on, up to the check the scan relied on (a later check is not on it); a run that
relied on none has nothing to chart. Slow: the report draws all its figures (~15 CPU-s).
"""

from __future__ import annotations

import json
import re

import pytest

from tests.helpers.cli import run_main
from tests.test_assurance import _bench, _check, _scan


@pytest.mark.slow
def test_the_compare_report_charts_the_checks_the_actual_run_relied_on(capsys, tmp_path):
    bench, store = _bench(tmp_path, assurance="warn"), tmp_path / "s.sqlite"
    for day in (1, 2, 3):
        _check(capsys, bench, store, day, day)
    code, out, err = _scan(capsys, bench, store, 3, tmp_path)
    assert code == 0, err
    relied = out.strip().splitlines()[-1]
    later = _check(capsys, bench, store, 4, 4)["run"]  # after the scan: not what it relied on
    code, out, err = _scan(capsys, bench, store, 4, tmp_path)
    other = out.strip().splitlines()[-1]
    report = tmp_path / "rep"
    code, out, err = run_main(capsys, "compare", relied, other, "--store", store, "--out", report, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert "fig-assurance" in summary["figures"]
    html = (report / "report.html").read_text()
    (img,) = re.findall(r'<img id="fig-assurance" alt="([^"]*)" src="data:image/png;base64,', html)
    assert "grey tile" in img and (report / "figures" / "fig-assurance.png").stat().st_size > 10_000
    # the chart stops at the check of day 3: the report's chart of the later scan has one more point
    from bench.assurance import relied_charts
    from bench.store import RunStore

    with RunStore(store, create=False) as s:
        (first,) = relied_charts(s, s.to_record(relied).meta)
        (second,) = relied_charts(s, s.to_record(other).meta)
        assert [h["date"] for h in first[1]] == ["2026-12-01", "2026-12-02", "2026-12-03"]
        assert second[1][-1]["run"] == later and len(second[2].values) == 4
    # a run on a bench that declares no assurance relied on no check: nothing to chart
    (tmp_path / "off").mkdir()
    code, out, err = _scan(capsys, _bench(tmp_path / "off", assurance="off"), store, 4, tmp_path)
    assert code == 0, err
    with RunStore(store, create=False) as s:
        assert relied_charts(s, s.to_record(out.strip().splitlines()[-1]).meta) == []
