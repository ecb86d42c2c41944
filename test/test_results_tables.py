"""docs/results.md agrees with the runs behind it.

- The generated claims blocks (cr_control.experiments.results_tables) equal what the claims
  of the deterministic ``cr_reproduce --quick`` run give (the ``reproduce_quick`` fixture
  of conftest.py: one run per test session, ~3 min on 2 cores); the renderer and the check
  are tested on synthetic claims.
- The hand-written chapter 3 and chapter 5 tables: a row whose printed number differs from
  the run at the printed precision fails.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cr_control.experiments import results_tables as rt
from cr_control.experiments.evaluate import run_point

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results.md"


def table_rows(heading: str) -> list[list[str]]:
    """The cells of the first table after ``heading`` (header and rule rows skipped)."""
    lines = RESULTS.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(heading))
    rows, seen = [], False
    for line in lines[start + 1:]:
        if line.startswith("|"):
            seen = True
            rows.append([c.strip() for c in line.strip("|").split("|")])
        elif seen:
            break
    return rows[2:]


def number(cell: str) -> tuple[float, int]:
    """(value, decimals) of the first number in ``cell``."""
    text = re.search(r"-?\d+(?:\.(\d+))?", cell)
    assert text, cell
    return float(text.group(0)), len(text.group(1) or "")


@pytest.mark.parametrize("scheme", ["adaptive_impedance", "robust_adaptive_impedance",
                                    "nn_adaptive_impedance"])
def test_chapter3_table(scheme):
    row = next(r for r in table_rows("## Chapter 3") if r[0].startswith(scheme + " "))
    printed, decimals = number(row[1])                   # RMS ||e|| 5-10 s, mm
    result = run_point(scheme, None, 10.0, {}, {})
    assert result["status"] == "ok"
    assert round(1e3 * result["pos_err_rms_last_half_m"], decimals) == printed


@pytest.mark.parametrize("scheme, label", [("impedance", "impedance, thesis 2 N, 60 ms"),
                                           ("fuzzy_unidirectional", "fuzzy, thesis 2 N, 60 ms")])
def test_chapter5_table(scheme, label):
    row = next(r for r in table_rows("## Chapter 5") if r[0] == label)
    result = run_point(scheme, None, 10.0, {}, {})
    separated, _ = number(row[1])                        # ms
    f_min, decimals = number(row[2])                     # N
    assert 1e3 * result["separated_s"] == separated
    assert round(result["f_m_min_after_N"], decimals) == f_min


CLAIMS = [
    {"chapter": "3", "claim": "3.5.1: contact kept | bounded", "rule": "r",
     "measured": {"pos_err_mm": 12.583941, "status": "ok", "grid_N": [2.0, 6.3]},
     "verdict": "reproduced"},
    {"chapter": "C", "claim": "C: q1 -> 0", "rule": "r", "measured": {"q1_m": 2.5e-10},
     "verdict": "not reproduced"},
]
DOC = "# Results\n\n## Chapter 3: plane\n\ntext\n\n## Chapter 4 and appendix C: chain\n\nmore\n"


def test_block_renders_every_claim_of_a_chapter():
    text = rt.block(CLAIMS, "3")
    assert text.splitlines()[0] == "<!-- claims:begin chapter=3 -->"
    assert "| 3.5.1: contact kept \\| bounded | pos_err_mm = 12.58; status = ok; " \
        "grid_N = [2, 6.3] | **reproduced** |" in text
    assert "q1" not in text and text.endswith("<!-- claims:end chapter=3 -->")


def test_a_diverged_run_is_printed_to_two_significant_digits():
    """How far a diverged run grew before its guard stopped it is floating-point history
    (797.3 and 796.3 N on two CPUs, same code): two digits; a run that did not diverge
    keeps four."""
    def row(status):
        claim = {"chapter": "4", "claim": "c", "rule": "r", "verdict": "v",
                 "measured": {"ss_error_N": 797.3, "f_max_N": [3683.0], "status": status}}
        return rt.block([claim], "4").splitlines()[3]

    assert "ss_error_N = 8e+02; f_max_N = [3.7e+03]; status = diverged" in row("diverged")
    assert "ss_error_N = 797.3; f_max_N = [3683]; status = ok" in row("ok")


def test_write_places_blocks_under_their_chapters_and_check_agrees():
    text = rt.write(CLAIMS, DOC)
    assert rt.differences(CLAIMS, text) == []
    assert text.index("chapter=3") < text.index("## Chapter 4") < text.index("chapter=C")
    assert rt.write(CLAIMS, text) == text                       # idempotent
    fresh = rt.write(CLAIMS[:1], "# Results\n")                 # no heading: a new section
    assert "## Chapter 3 (claims)" in fresh and rt.differences(CLAIMS[:1], fresh) == []


def test_check_fails_on_a_changed_number_a_missing_or_a_stale_block():
    text = rt.write(CLAIMS, DOC)
    changed = [dict(CLAIMS[0], measured={**CLAIMS[0]["measured"], "pos_err_mm": 12.59}),
               CLAIMS[1]]
    assert rt.differences(changed, text) == ["chapter 3: the claims block differs from "
                                             "claims.json"]
    assert rt.differences([*CLAIMS, dict(CLAIMS[1], chapter="6")], text) == \
        ["chapter 6: no generated claims block"]
    assert rt.differences(CLAIMS[:1], text) == ["chapter C: a claims block but no claims"]
    assert "chapter=C" not in rt.write(CLAIMS[:1], text)


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "claims.json"
    bad.write_text("{not json")
    assert rt.main([str(bad), "--check", str(RESULTS)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not JSON" in err[0]


@pytest.mark.ros
def test_results_md_claims_blocks_equal_the_quick_run(reproduce_quick):
    """docs/results.md's generated blocks are what the quick run's claims.json gives
    (regenerate: cr_reproduce --quick --out DIR --write-tables docs/results.md)."""
    claims = rt.load(reproduce_quick / "claims.json")
    assert rt.differences(claims, RESULTS.read_text()) == []
    assert rt.main([str(reproduce_quick / "claims.json"), "--check", str(RESULTS)]) == 0


@pytest.mark.ros
def test_cr_reproduce_write_tables_leaves_an_agreeing_results_md_unchanged(reproduce_quick,
                                                                          tmp_path):
    """``cr_reproduce --quick --out DIR --write-tables FILE`` (resuming the session's quick
    run: no point is computed again) rewrites FILE's blocks; docs/results.md agrees, so a
    copy of it comes back byte for byte, and a copy with a block edited is repaired."""
    import shutil

    from cr_control.experiments import reproduce

    shutil.copytree(reproduce_quick / "runs", tmp_path / "runs")
    target = tmp_path / "results.md"
    target.write_text(RESULTS.read_text().replace("| **reproduced** |", "| **typed** |", 1))
    assert rt.differences(rt.load(reproduce_quick / "claims.json"), target.read_text())
    assert reproduce.main(["--quick", "--out", str(tmp_path), "--write-tables",
                           str(target)]) == 0
    assert target.read_text() == RESULTS.read_text()
