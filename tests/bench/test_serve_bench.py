"""``dfc benchmark serve``: its summary statistics, tables and tile choice, and one small run over HTTP."""

import json
import random
import re

import numpy as np
import pytest

from dfc.bench.speed.serve import (
    latency_summary,
    latency_table,
    throughput_table,
    tile_paths,
)
from dfc.serve.iiif import parse_image_request

from ..cli.test_cli import run


def test_latency_summary_in_milliseconds():
    s = latency_summary(np.arange(1, 101) / 1000)  # 1 .. 100 ms
    assert s["n"] == 100 and s["median_ms"] == pytest.approx(50.5)
    assert s["p95_ms"] == pytest.approx(95.05) and s["p99_ms"] == pytest.approx(99.01)
    assert latency_summary([0.25]) == {"n": 1, "median_ms": 250.0, "p95_ms": 250.0, "p99_ms": 250.0}


def test_tables():
    text = latency_table({"cold": latency_summary([0.010, 0.030]), "warm": latency_summary([0.001])})
    lines = text.splitlines()
    assert lines[0].split() == ["tiles", "n", "median", "p95", "p99"]
    assert lines[1].split()[:4] == ["cold", "2", "20.0", "ms"] and lines[2].split()[:4] == ["warm", "1", "1.0", "ms"]
    rows = throughput_table([{"clients": 1, "tiles": 10, "seconds": 2.0}, {"clients": 16, "tiles": 48, "seconds": 4.0}])
    assert [ln.split() for ln in rows.splitlines()[1:]] == [["1", "10", "2.00", "5.0", "200.0"],
                                                            ["16", "48", "4.00", "12.0", "1333.3"]]


def test_tile_paths_are_distinct_valid_iiif_tiles():
    side = 256 * 1024
    paths = tile_paths("f", side, 200, random.Random(1), deepest=1, coarsest=64)
    assert len(set(paths)) == 200 and paths == tile_paths("f", side, 200, random.Random(1), deepest=1, coarsest=64)
    for p in paths:
        ident, region, size, rotation, qf = p.split("/")[2:]
        request = parse_image_request(region, size, rotation, qf, side, side)
        x, y, w, h = request.region
        s = w // request.size[0]
        assert ident == "f" and 1 <= s <= 64 and w == 256 * s and x % w == 0 and y % h == 0


def test_small_benchmark_run_has_no_errors(tmp_path, capsys):
    out = tmp_path / "serve.json"
    code, stdout, err = run(["benchmark", "serve", "--tiles", "5", "--clients", "1,2", "--throughput-tiles", "2",
                             "--load-requests", "20", "--load-clients", "4", "--load-pool", "4", "--cache-mb", "1",
                             "--json", out], capsys)
    assert code == 0, err
    figures = json.loads(out.read_text())
    assert figures["grid_scale"] == 1024 and figures["latency"]["beyond the input, rendered (cold)"]["n"] == 5
    assert [r["clients"] for r in figures["throughput"]] == [1, 2]
    assert all(r["errors"] == 0 for r in figures["throughput"])
    load = figures["load"]
    assert load["requests"] == 20 and load["errors"] == 0 and load["peak_mb"] >= load["rss_before_mb"] > 0
    assert re.search(r"load test: 20 requests from 4 clients .* 0 errors", stdout)
