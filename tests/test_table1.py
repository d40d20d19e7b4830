"""Table 1 (recursive vs direct data processing) against the paper's printed values."""

import math

import pytest

from reports.table1 import PAPER_RATIO, check_against_paper, format_count, format_markdown, main, rows

#: The paper's Faces and Dimensions columns, levels 1..8.
PAPER_FACES = [4, 10, 22, 46, 94, 190, 382, 766]
PAPER_DIMS = [9, 36, 144, 576, 2304, 9216, 36864, 147456]


def test_unordered_count_matches_paper_in_all_rows():
    table = rows()
    assert [f"1:{format_count(r['unordered'])}" for r in table] == list(PAPER_RATIO)
    check_against_paper(table)


def test_exact_small_values():
    table = rows()
    assert [r["unordered"] for r in table[:4]] == [1, 42, 6783, 3746171]
    assert table[3]["unordered"] == math.comb(69, 5) // 3


def test_faces_dims_one_rings_match_paper():
    table = rows()
    assert [r["faces"] for r in table] == PAPER_FACES
    assert [r["dims"] for r in table] == PAPER_DIMS
    assert [r["one_rings"] for r in table] == [4 ** (L - 1) for L in range(1, 9)]
    assert [r["variations"] for r in table] == [6] + [3] * 7


def test_ordered_count():
    table = rows()
    assert table[1]["ordered"] == 6**4 == 1296
    assert table[7]["ordered"] == 6**16384


def test_check_detects_a_mismatch():
    table = rows()
    table[2] = {**table[2], "unordered": table[2]["unordered"] + 1}
    with pytest.raises(AssertionError, match="level 3"):
        check_against_paper(table)


def test_format_count():
    assert format_count(9999) == "9999"
    assert format_count(3746171) == "3.75E+06"
    assert format_count(99950) == "1.00E+05"


def test_markdown_has_eight_data_rows_and_both_formulas():
    text = format_markdown(rows())
    data = [line for line in text.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert len(data) == 8
    assert "C(n_L + 5, 5) / v_L" in text and "6^n_L" in text and "paper's" in text


def test_main_writes_file(tmp_path, capsys):
    out = tmp_path / "table1.md"
    assert main(["--out", str(out)]) == 0
    assert out.read_text() == format_markdown(rows())
    assert "1:3.28E+18" in capsys.readouterr().out
