"""Result files written by ``dfc benchmark`` and read back from markdown tables (``dfc.bench.results``)."""

import json

from click.testing import CliRunner

from dfc.bench.results import SCHEMA, tables_from_markdown, tables_from_record, validate
from dfc.cli import cli


def test_markdown_tables_keep_empty_and_escaped_cells():
    text = "# Title\n\nnotes\n\n| | a | b |\n|---|---:|---:|\n| x | 1,234 | |\n| y | p \\| q | 56.30 |\n"
    (table,) = tables_from_markdown(text)
    assert table == {"title": "Title", "columns": ["", "a", "b"], "rows": [["x", "1,234", ""], ["y", "p | q", "56.30"]]}


def test_record_lists_and_scalars_become_tables():
    tables = tables_from_record({"n": 3, "runs": [{"t": 1, "s": 0.5}, {"t": 2, "extra": [1]}]})
    assert tables[0] == {"title": "figures", "columns": ["figure", "value"], "rows": [["n", 3]]}
    assert tables[1] == {"title": "runs", "columns": ["t", "s", "extra"], "rows": [[1, 0.5, None], [2, None, "[1]"]]}


def test_benchmark_json_is_a_result_file_that_keeps_the_figures(tmp_path):
    out = tmp_path / "mesh.json"
    result = CliRunner().invoke(cli, ["benchmark", "mesh", "--curves", "3", "--triangles", "300", "--json", str(out)])
    assert result.exit_code == 0, result.output
    doc = json.loads(out.read_text())
    assert validate(doc) == [] and doc["schema"] == SCHEMA and doc["source"] == "measured"
    assert doc["title"] == "dfc benchmark mesh" and "--triangles 300" in doc["command"]
    assert doc["triangles"] > 0
    assert ["triangles", doc["triangles"]] in doc["tables"][0]["rows"]


def test_a_bench_record_becomes_a_result_file_keeping_its_keys():
    from dfc.bench.results import publish_record

    markdown = "# dfc bench: shapes\n\nnotes\n\n| method | bytes |\n|---|---:|\n| dfc | 2048 |\n"
    doc = publish_record({"methods": {"dfc": {"bytes": 2048}}, "title": "kept out"}, markdown, command="dfc bench x")
    assert validate(doc) == [] and doc["command"] == "dfc bench x" and doc["title"] == "dfc bench: shapes"
    assert doc["methods"] == {"dfc": {"bytes": 2048}}
    assert doc["tables"] == [{"title": "dfc bench: shapes", "columns": ["method", "bytes"], "rows": [["dfc", "2048"]]}]


def test_rd_series_are_bytes_against_psnr_per_method_and_measure():
    from dfc.bench.results import rd_series

    point = {"bytes": 2000, "image_psnr": {"all": 40.123, "unmixed": 45.0}, "psnr": {"1": 40.0, "10": 50.0}}
    record = {"rd": True, "zoom_truth": True, "curves": {"dfc": [point, {"budget": 1000, "failed": "too small"}]},
              "runs": [{"methods": {"dfc": {"label": "dfc"}}}]}
    series = rd_series(record, "rd_x")
    assert [s["panel"] for s in series] == ["1×, all pixels", "1×, without mixed pixels", "10×, mean of the probes"]
    assert series[0] == {"figure": "rd_x", "panel": "1×, all pixels", "label": "dfc", "x": [2000], "y": [40.12],
                         "x_label": "bytes", "y_label": "PSNR (dB)", "x_log2": True}
    assert series[2]["y"] == [50.0]
