"""Table 1 of the paper: the relation between recursive and direct data processing.

`python -m reports.table1 [--out table1.md]` prints the table, checks it against the paper's
printed ratio column and, with ``--out``, writes it as Markdown.

A level-L ring holds ``n_L = 4**(L-1)`` one-rings (DESIGN.md §3). Matching it recursively (one
BMUofN pass per level over ``v_L`` variations) is compared with matching it directly, where every
one-ring may take any of the 6 level-1 variations. Two counts of the direct case are given
(DESIGN.md §6):

- unordered: ``C(n_L + 5, 5) / v_L``, the number of multisets of 6 variations over the
  ``n_L`` one-rings, per recursive variation. This is the paper's "Recursive : Direct" column.
- ordered: ``6**n_L``, every one-ring oriented independently, per vector.
"""

from __future__ import annotations

import argparse
import math
from fractions import Fraction
from pathlib import Path

from meshsom.rings import MAX_LEVEL, dims, faces_in_walk
from meshsom.variations import n_variations

__all__ = ["PAPER_RATIO", "check_against_paper", "format_count", "format_markdown", "main", "rows"]

#: Variations of one one-ring in the direct count: 3 start leaves x mirror (DESIGN.md §3).
ONE_RING_VARIATIONS = 6
#: Rings nested per level: a level-L ring is four level-(L-1) rings.
RINGS_PER_LEVEL = 4
#: The paper's "Recursive : Direct" column, levels 1..8, as printed.
PAPER_RATIO = ("1:1", "1:42", "1:6783", "1:3.75E+06", "1:3.24E+09", "1:3.17E+12", "1:3.21E+15", "1:3.28E+18")
#: The paper prints counts below this exactly and larger ones in scientific notation.
EXACT_BELOW = 10_000
#: Significant digits of the paper's scientific notation.
SIGNIFICANT = 3


def one_rings(level: int) -> int:
    """Number of one-rings in a level-L ring: ``4**(L-1)``."""
    return RINGS_PER_LEVEL ** (level - 1)


def rows(max_level: int = MAX_LEVEL) -> list[dict]:
    """The rows of Table 1.

    Parameters
    ----------
    max_level : int
        Last level (the paper's table stops at 8).

    Returns
    -------
    rows : list of dict
        One per level, with keys ``level``, ``one_rings`` (n_L), ``faces`` (face slots of the
        walk), ``dims`` (vector length), ``variations`` (v_L of the recursive BMUofN),
        ``unordered`` (``C(n_L + 5, 5) / v_L``; int when exact, else Fraction), ``ordered``
        (``6**n_L``, int) and ``paper_ratio`` (the paper's printed string, or None beyond it).
    """
    if not (isinstance(max_level, int) and max_level >= 1):
        raise ValueError(f"max_level must be an integer >= 1; received {max_level!r}")
    out = []
    for level in range(1, max_level + 1):
        n = one_rings(level)
        v = n_variations(level)
        unordered = Fraction(math.comb(n + ONE_RING_VARIATIONS - 1, ONE_RING_VARIATIONS - 1), v)
        out.append({
            "level": level,
            "one_rings": n,
            "faces": faces_in_walk(level),
            "dims": dims(level),
            "variations": v,
            "unordered": int(unordered) if unordered.denominator == 1 else unordered,
            "ordered": ONE_RING_VARIATIONS**n,
            "paper_ratio": PAPER_RATIO[level - 1] if level <= len(PAPER_RATIO) else None,
        })
    return out


def format_count(x: int | Fraction) -> str:
    """A count as the paper prints it: exact below 1e4, else 3 significant digits (``3.75E+06``).

    Parameters
    ----------
    x : int or Fraction

    Returns
    -------
    str
    """
    if x < EXACT_BELOW and Fraction(x).denominator == 1:
        return str(int(x))
    if x < EXACT_BELOW:
        return f"{float(x):.{SIGNIFICANT}g}"
    return _scientific(x)


def _scientific(x: int | Fraction) -> str:
    """``x`` with SIGNIFICANT digits, ``d.ddE+XX``; exact for ints too large for a float."""
    x = Fraction(x)
    exp = math.floor(math.log10(x.numerator) - math.log10(x.denominator))
    while Fraction(10) ** exp > x:  # float log10 can be one off near powers of ten
        exp -= 1
    while Fraction(10) ** (exp + 1) <= x:
        exp += 1
    mant = math.floor(x / Fraction(10) ** (exp - SIGNIFICANT + 1) + Fraction(1, 2))  # half up
    if mant >= 10**SIGNIFICANT:  # rounding carried into a new digit
        mant, exp = mant // 10, exp + 1
    digits = str(mant)
    return f"{digits[0]}.{digits[1:]}E{exp:+03d}"


def format_markdown(table: list[dict]) -> str:
    """Table 1 as Markdown, both direct counts, and a note with their formulas.

    Parameters
    ----------
    table : list of dict
        From :func:`rows`.

    Returns
    -------
    str
    """
    lines = [
        "| Level | 1-Rings n_L | Faces | Dimensions | Variations v_L | Recursive : Direct (unordered) "
        "| Ordered per vector | Paper |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in table:
        lines.append(
            f"| {r['level']} | {r['one_rings']} | {r['faces']} | {r['dims']} | {r['variations']} "
            f"| 1:{format_count(r['unordered'])} | {format_count(r['ordered'])} "
            f"| {r['paper_ratio'] or ''} |"
        )
    lines += [
        "",
        f"Notes. n_L = {RINGS_PER_LEVEL}^(L-1) one-rings per level-L ring; Faces = 3 * 2^L - 2 face slots of "
        f"the walk; Dimensions = 9 * 4^(L-1); v_L = variations of the recursive BMUofN "
        f"({n_variations(1)} at level 1, {n_variations(2)} above).",
        f"- Unordered: C(n_L + {ONE_RING_VARIATIONS - 1}, {ONE_RING_VARIATIONS - 1}) / v_L, the multisets of "
        f"the {ONE_RING_VARIATIONS} one-ring variations over the n_L one-rings, per recursive variation. "
        "This is the paper's \"Recursive : Direct\" column (equal in every row, as printed).",
        f"- Ordered: {ONE_RING_VARIATIONS}^n_L, every one-ring oriented independently, per vector "
        "(not the paper's column).",
    ]
    return "\n".join(lines) + "\n"


def check_against_paper(table: list[dict]) -> None:
    """Raise AssertionError unless the unordered count matches the paper's column in every row.

    Parameters
    ----------
    table : list of dict
        From :func:`rows`; rows without a paper value are ignored, and all eight of the paper's
        levels must be present.

    Raises
    ------
    AssertionError
        Naming the rows that differ.
    """
    printed = [r for r in table if r["paper_ratio"] is not None]
    if len(printed) != len(PAPER_RATIO):
        raise AssertionError(f"expected the paper's {len(PAPER_RATIO)} levels; received {len(printed)}")
    bad = [
        f"level {r['level']}: 1:{format_count(r['unordered'])} != {r['paper_ratio']}"
        for r in printed
        if f"1:{format_count(r['unordered'])}" != r["paper_ratio"]
    ]
    if bad:
        raise AssertionError("Table 1 differs from the paper: " + "; ".join(bad))


def main(argv: list[str] | None = None) -> int:
    """Print Table 1, check it against the paper, and optionally write it (``--out FILE``)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, help="write the Markdown table to this file")
    args = p.parse_args(argv)
    table = rows()
    text = format_markdown(table)
    print(text, end="")
    check_against_paper(table)
    print(f"\nAll {len(PAPER_RATIO)} rows match the paper's \"Recursive : Direct\" column.")
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
