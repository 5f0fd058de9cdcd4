"""Numbers the docs quote agree with the results files they were taken from.

Every policy table of docs/training.md names the evaluation it shows (``--json-out
docs/figures/NAME.json`` in the paragraph above it); each of its cells must be that file's figure
as ``examples/evaluate_policy.py`` prints it. The summaries quoted in prose (the README's three
seeds) are checked against the same files.
"""

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures"


def _tables(text: str):
    """``(json name, header cells, rows, line)`` of every ``| policy |`` table, with the results file
    that the closest ``--json-out`` above it in its section wrote (else the file named below it)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not line.startswith("| policy |"):
            continue
        start, end = i, i + 1
        while start > 0 and not lines[start - 1].startswith("#"):
            start -= 1
        while end < len(lines) and not lines[end].startswith("#"):
            end += 1
        # the file the closest --json-out above it in its section wrote, else the one named below it
        written = re.findall(r"--json-out\s+docs/figures/([\w.]+\.json)", "\n".join(lines[start:i]))
        named = written[-1:] or re.findall(r"docs/figures/([\w.]+\.json)", "\n".join(lines[i:end]))
        rows = []
        for row in lines[i + 2:]:
            if not row.startswith("|"):
                break
            rows.append([c.strip() for c in row.strip("|").split("|")])
        yield (named[0] if named else None), [c.strip() for c in line.strip("|").split("|")], rows, i + 1


#: Row labels that name a run by what it is rather than by its seed.
LABELS = {"ppo, seed 2, time limit bootstrapped": "ppo:ppo_tlboot_seed2_s13",
          "ppo, seed 2, the limit as a terminal state": "ppo:ppo_default_seed2_s13"}


def _policy(label: str, results: dict) -> str | None:
    """The results key of a row label: ``ppo, seed 3`` -> ``ppo:<run folder of seed 3>``."""
    label = label.replace("*", "")
    if label in LABELS:
        return LABELS[label] if LABELS[label] in results else None
    seed = re.search(r"seed (\d+)", label)
    if label.startswith("ppo") and seed:
        found = [k for k in results if k.startswith("ppo:") and re.search(rf"seed{seed.group(1)}(\D|$)", k)]
        return found[0] if len(found) == 1 else None
    name = label.split()[0].rstrip(",").lower()
    return name if name in results else None


def _expected(header: str, r: dict) -> str | None:
    """The start of the cell under ``header`` for result ``r``, as evaluate_policy prints it."""
    f, s = r["final_step"], r["all_steps"]
    h = header.lower()
    if h.startswith("success (final"):
        return f"{f['success_rate']:.2f}"
    if h.startswith("success (all"):
        return f"{s['success_rate']:.2f}"
    if h.startswith("median / p90"):
        q = s if "all steps" in h else f
        return f"{q['translation_median_m']:.3f} / {q['translation_p90_m']:.3f}"
    if h == "mean return":
        return f"{r['mean_return']:.2f}"
    if h.startswith("distance"):
        return f"{r['start_distance_median_m']:.1f} -> {r['end_distance_median_m']:.1f}"
    return None


def _check_table(doc: str, name: str, header: list[str], rows: list[list[str]], where: int) -> int:
    results = json.loads((FIGURES / name).read_text())["results"]
    checked = 0
    for row in rows:
        if re.search(r"\bseeds\b", row[0]):  # several runs' figures in one cell ("0.132 / 0.122 / ...")
            continue
        key = _policy(row[0], results)
        assert key is not None, f"{doc}:{where}: row {row[0]!r} names no policy of {name}"
        for h, cell in zip(header[1:], row[1:], strict=True):
            want = _expected(h, results[key])
            if want is not None:
                cell = cell.replace("*", "")
                assert cell.startswith(want), f"{doc}:{where}: {row[0]} / {h}: {cell!r}, {name} says {want}"
                checked += 1
    return checked


def test_every_policy_table_matches_the_results_file_it_names():
    doc = "docs/training.md"
    tables = list(_tables((ROOT / doc).read_text()))
    assert len(tables) >= 8
    checked = 0
    from_files = 0
    for name, header, rows, where in tables:
        for row in rows:
            assert len(row) == len(header), f"{doc}:{where}: {row[0]!r}: {len(row)} of {len(header)} cells"
        if name is not None:  # a table measured without --json-out has no file to check against
            checked += _check_table(doc, name, header, rows, where)
            from_files += 1
    assert from_files >= 7 and checked > 250, (from_files, checked)


@pytest.mark.parametrize("doc", ["README.md", "docs/training.md"])
def test_the_three_seeds_summary_is_the_results_files(doc):
    warm = json.loads((FIGURES / "policy_evaluation_warm.json").read_text())["results"]
    spread = warm["ppo"]["across_runs"]
    text = " ".join((ROOT / doc).read_text().split())
    success, median = spread["success_rate"], spread["translation_median_m"]
    assert f"success {success['mean']:.3f}" in text
    assert f"{median['mean']:.3f} ± {median['std']:.3f} m" in text
    assert f"{spread['end_distance_median_m']['mean']:.1f} m" in text
    if doc == "README.md":  # the baselines it names
        for name in ("orbit", "greedy"):
            f = warm[name]["final_step"]
            assert f"{f['success_rate']:.2f}, {f['translation_median_m']:.3f} m" in text, name
