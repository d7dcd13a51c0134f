"""A table as Markdown, LaTeX and CSV: display strings for people, numbers for machines."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pandas as pd


@dataclasses.dataclass(frozen=True)
class Table:
    """One table.

    name: file stem (``table1``); title: caption; header: display column names;
    rows: display cells (strings); notes: lines under the table; data: the numbers, written as CSV.
    """

    name: str
    title: str
    header: list[str]
    rows: list[list[str]]
    notes: list[str]
    data: pd.DataFrame

    def markdown(self) -> str:
        def line(cells):
            return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

        out = [f"### {self.title}", "", line(self.header), line(["---"] * len(self.header))]
        out += [line(r) for r in self.rows]
        return "\n".join(out + [""] + [f"- {n}" for n in self.notes]) + "\n"

    def latex(self) -> str:
        def esc(text: str) -> str:
            for a, b in (("\\", "\\textbackslash{}"), ("&", "\\&"), ("%", "\\%"), ("_", "\\_"), ("#", "\\#"),
                         ("±", "$\\pm$"), ("×", "$\\times$"), ("~", "\\textasciitilde{}")):
                text = text.replace(a, b)
            return text

        out = ["\\begin{table}[t]", "\\centering", "\\footnotesize",
               "\\begin{tabular}{" + "l" * len(self.header) + "}", "\\hline",
               " & ".join(esc(h) for h in self.header) + " \\\\", "\\hline"]
        out += [" & ".join(esc(c) for c in r) + " \\\\" for r in self.rows]
        out += ["\\hline", "\\end{tabular}", f"\\caption{{{esc(self.title)}. " + " ".join(esc(n) for n in self.notes)
                + "}", f"\\label{{tab:{self.name}}}", "\\end{table}"]
        return "\n".join(out) + "\n"

    def write(self, folder: Path) -> list[Path]:
        folder.mkdir(parents=True, exist_ok=True)
        paths = [folder / f"{self.name}.{ext}" for ext in ("md", "tex", "csv")]
        paths[0].write_text(self.markdown())
        paths[1].write_text(self.latex())
        self.data.to_csv(paths[2], index=False, float_format="%.6g")
        return paths


def fmt(value: float, digits: int = 3) -> str:
    """A number for display ("-" when missing)."""
    return "-" if value is None or pd.isna(value) else f"{value:.{digits}f}"


def fmt_pm(mean: float, std: float, digits: int = 3) -> str:
    return "-" if pd.isna(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}"


def fmt_rate(rate: float, low: float, high: float) -> str:
    return "-" if pd.isna(rate) else f"{rate:.3f} [{low:.3f}, {high:.3f}]"
