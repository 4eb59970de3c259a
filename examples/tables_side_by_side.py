"""The paper's Tables 2–3 from several reproductions, side by side.

Each argument names one finished ``membrax reproduce`` folder as ``label=folder`` (its ``table2.csv`` and
``table3.csv``). For every case (σc × t_m) it prints the peak φ' (external, internal) and the additional
stresses Δσ1 and Δσ3 (platen cylinder) of each run (``--paper``: and the reference study's), then each
run's largest difference from the first run's. For comparing membrane contact models and laws:

    python examples/tables_side_by_side.py nodes=results/paper faces=results/paper_faces \
        gent=results/paper_gent

It reads only the CSV files (seconds) and writes nothing; ``--markdown`` prints the tables in Markdown.
"""

import argparse
import csv
from pathlib import Path

COLUMNS = {
    "table2.csv": (
        ("φ'ext (°)", "peak_external_friction_angle_deg"),
        ("φ'int (°)", "peak_internal_friction_angle_deg"),
    ),
    "table3.csv": (
        ("Δσ1 (kPa)", "additional_sigma1_kpa"),
        ("Δσ3 (kPa)", "additional_sigma3_kpa"),
    ),
}


def read_run(folder: Path, prefix: str = "") -> dict:
    """{(σc kPa, t_m mm): {column label: value}} of one reproduction folder (``prefix="paper_"``: the
    paper's figures its tables print beside membrax's)."""
    cases: dict = {}
    for name, columns in COLUMNS.items():
        path = folder / name
        if not path.exists():
            raise SystemExit(
                f"{path}: not found; give a folder written by `membrax reproduce` (it holds {name})"
            )
        with path.open() as handle:
            for line, row in enumerate(csv.DictReader(handle), start=2):
                try:
                    key = (float(row["cell_pressure_kpa"]), float(row["membrane_thickness_mm"]))
                    values = {label: float(row[prefix + field]) for label, field in columns}
                except (KeyError, ValueError) as error:
                    message = f"{path}, line {line}: cannot read {error}; is this a reproduction's table?"
                    raise SystemExit(message) from None
                cases.setdefault(key, {}).update(values)
    return cases


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="label=folder, the first is the reference")
    parser.add_argument("--markdown", action="store_true", help="print Markdown tables")
    parser.add_argument("--paper", action="store_true", help="add the paper's figures as the last run")
    args = parser.parse_args(argv)
    runs = {}
    for item in args.runs:
        label, sep, folder = item.partition("=")
        if not sep or not label or not folder:
            raise SystemExit(f"{item!r}: give each run as label=folder, e.g. faces=results/paper_faces")
        runs[label] = read_run(Path(folder))
    if args.paper:
        runs["paper"] = read_run(Path(args.runs[0].partition("=")[2]), prefix="paper_")
    reference_label, reference = next(iter(runs.items()))
    for label, cases in runs.items():
        if set(cases) != set(reference):
            raise SystemExit(
                f"{label}: its cases {sorted(cases)} differ from {reference_label}'s {sorted(reference)}"
            )
    labels = [label for _, columns in COLUMNS.items() for label, _ in columns]
    header = ["σc (kPa)", "t_m (mm)"] + [f"{column}, {run}" for column in labels for run in runs]
    rows = [
        [f"{pressure:g}", f"{thickness:g}"]
        + [f"{runs[run][(pressure, thickness)][column]:.2f}" for column in labels for run in runs]
        for pressure, thickness in sorted(reference, key=lambda key: (key[1], key[0]))
    ]
    if args.markdown:
        print("| " + " | ".join(header) + " |")
        print("|" + "---:|" * len(header))
        for row in rows:
            print("| " + " | ".join(row) + " |")
    else:
        widths = [max(len(cell) for cell in column) for column in zip(header, *rows, strict=True)]
        for row in [header, *rows]:
            print("  ".join(cell.rjust(width) for cell, width in zip(row, widths, strict=True)))
    print()
    for label, cases in list(runs.items())[1:]:
        spans = []
        for column in labels:
            differences = [cases[key][column] - reference[key][column] for key in reference]
            spans.append(f"{column} {min(differences):+.2f} to {max(differences):+.2f}")
        print(f"{label} − {reference_label}: " + "; ".join(spans))


if __name__ == "__main__":
    main()
