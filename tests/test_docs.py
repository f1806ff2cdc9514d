"""The generated results page and figures match the committed result files (``python -m dfc.bench.docs``)."""

import json
import re
from pathlib import Path

import pytest

from dfc.bench.docs import check, figures, generate, line_colours, load_results, results_markdown
from dfc.bench.results import validate

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
DOCS = ROOT / "docs"


def test_every_result_file_follows_the_schema():
    files = sorted(RESULTS.glob("*.json"))
    assert files
    for path in files:
        assert validate(json.loads(path.read_text())) == [], path.name


def test_generated_docs_are_in_sync_with_the_committed_results():
    assert check(RESULTS, DOCS) == []


def test_regenerating_writes_the_committed_page_and_every_named_figure(tmp_path):
    pytest.importorskip("matplotlib")
    written = generate(RESULTS, tmp_path)
    assert (tmp_path / "results.md").read_text() == (DOCS / "results.md").read_text()
    expected = {f"{name}.png" for name in figures(load_results(RESULTS))}
    assert expected and {p.name for p in written if p.suffix == ".png"} == expected
    assert {p.name for p in (tmp_path / "figures").glob("*.png")} == expected


def test_check_reports_a_changed_result_and_a_missing_figure(tmp_path):
    results, docs = tmp_path / "results", tmp_path / "docs"
    results.mkdir()
    (docs / "figures").mkdir(parents=True)
    doc = {"schema": "dfc-result/1", "title": "t", "page": "bench", "command": "dfc bench x", "date": "2026-01-01",
           "commit": None, "machine": None, "source": "measured",
           "tables": [{"title": "", "columns": ["a", "b"], "rows": [["1", "2"]]}],
           "series": [{"figure": "f", "panel": "p", "label": "dfc", "x": [1, 2], "y": [3, 4]}]}
    (results / "r.json").write_text(json.dumps(doc))
    (docs / "results.md").write_text(results_markdown(load_results(results)))
    assert check(results, docs) == ["figure figures/f.png is missing"]
    (docs / "figures" / "f.png").write_bytes(b"")
    assert check(results, docs) == []
    doc["tables"][0]["rows"][0][1] = "3"
    (results / "r.json").write_text(json.dumps(doc))
    assert len(check(results, docs)) == 1


def test_a_method_keeps_its_colour_in_every_panel_of_a_figure():
    panels = [["dfc", "JPEG XL", "AVIF", "WebP", "JPEG 2000"], ["dfc", "JPEG XL", "AVIF", "JPEG 2000"], ["AVIF"]]
    colour = line_colours(panels, ["c0", "c1", "c2", "c3"])
    assert colour == {"dfc": "black", "JPEG XL": "c0", "AVIF": "c1", "WebP": "c2", "JPEG 2000": "c3"}
    assert line_colours([["a", "b", "c"]], ["x", "y"])["c"] == "x"  # the cycle repeats


def test_a_file_off_the_schema_is_refused_by_name(tmp_path):
    (tmp_path / "bad.json").write_text(json.dumps({"schema": "dfc-result/1", "title": "t"}))
    with pytest.raises(ValueError, match="bad.json"):
        load_results(tmp_path)


def _anchors(path: Path) -> set[str]:
    text = path.read_text()
    heads = {re.sub(r"[^\w\- ]", "", line.lstrip("#").replace("`", "").strip().lower()).replace(" ", "-")
             for line in text.splitlines() if line.startswith("#")}
    return heads | set(re.findall(r'<a id="([^"]+)"', text))


def test_every_link_of_the_readme_and_docs_resolves_inside_the_repository():
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "benchmarks" / "README.md", *sorted(DOCS.glob("*.md"))]
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if target.startswith(("http://", "https://")):
                continue
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page.resolve()
            if ROOT.resolve() not in resolved.parents or not resolved.exists():
                broken.append(f"{page.name}: {target}")
            elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
                broken.append(f"{page.name}: {target} (no such anchor)")
    assert broken == []
