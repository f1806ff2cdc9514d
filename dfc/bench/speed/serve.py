"""``dfc benchmark serve``: tile latency and throughput of ``dfc serve``, and a bounded load test.

Starts ``dfc serve FILE --port 0`` as a child process on 127.0.0.1 (nothing else is contacted) and requests
256 × 256 PNG tiles over HTTP/1.1 keep-alive connections, as a deep-zoom viewer does:

- latency (median, p95, p99 in ms, client side): the first tile after the server starts; ``--tiles`` distinct
  tiles beyond the input's resolution, rendered on request (cold: not in the cache); the same tiles again (warm:
  from the cache); and the input-resolution tile (anti-aliased: 64 points in the pixels a curve crosses); then the
  cold tiles rendered and encoded in this process on one thread, wall and CPU time (the CPU time is what an idle
  core takes: on a shared machine the wall time also counts waiting for a core);
- throughput (tiles/s, every tile rendered) with 1, 2 and 16 concurrent clients (``--clients``);
- a load test: ``--load-requests`` requests from ``--load-clients`` clients drawn from a pool of ``--load-pool``
  tiles (a viewer panning back and forth: hits and misses), stopped after ``--time-limit`` seconds; it counts
  errors and reports the server's resident memory before and at its peak against the ``--cache-mb`` bound.
"""

from __future__ import annotations

import http.client
import json
import math
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import click
import numpy as np

from ...command import json_option, quiet_option, stdout_taken, write_json
from ..neighbour import SAMPLES
from ..timing import _status

TILE = 256


def latency_summary(seconds) -> dict:
    """{"n", "median_ms", "p95_ms", "p99_ms"} of latencies in seconds (numpy's linear percentiles)."""
    ms = 1e3 * np.asarray(seconds, dtype=np.float64)
    return {"n": int(ms.size), "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
            "p99_ms": float(np.percentile(ms, 99))}


def latency_table(rows: dict[str, dict]) -> str:
    """A text table of ``latency_summary`` rows by name."""
    lines = [f"{'tiles':<34} {'n':>5} {'median':>9} {'p95':>9} {'p99':>9}"]
    for name, s in rows.items():
        lines.append(f"{name:<34} {s['n']:>5} {s['median_ms']:>6.1f} ms {s['p95_ms']:>6.1f} ms {s['p99_ms']:>6.1f} ms")
    return "\n".join(lines)


def throughput_table(rows: list[dict]) -> str:
    """A text table of throughput rows {"clients", "tiles", "seconds"}: tiles per second and per client."""
    lines = [f"{'clients':>7} {'tiles':>6} {'seconds':>8} {'tiles/s':>8} {'ms/tile/client':>15}"]
    for r in rows:
        rate = r["tiles"] / r["seconds"]
        lines.append(f"{r['clients']:>7} {r['tiles']:>6} {r['seconds']:>8.2f} {rate:>8.1f} "
                     f"{1e3 * r['clients'] / rate:>15.1f}")
    return "\n".join(lines)


def tile_paths(ident: str, side: int, count: int, rng: random.Random, *, deepest: int = 1,
               coarsest: int = 512) -> list[str]:
    """``count`` distinct IIIF tile paths of a ``side × side`` image at random levels (scale factors ``deepest`` ..
    ``coarsest``, powers of two) and positions, as a viewer asks for them."""
    levels = [2 ** k for k in range(int(math.log2(deepest)), int(math.log2(coarsest)) + 1)]
    seen: set[str] = set()
    while len(seen) < count:
        s = rng.choice(levels)
        span = TILE * s
        n = math.ceil(side / span)
        x, y = rng.randrange(n) * span, rng.randrange(n) * span
        w, h = min(span, side - x), min(span, side - y)
        seen.add(f"/iiif/{ident}/{x},{y},{w},{h}/{math.ceil(w / s)},{math.ceil(h / s)}/0/default.png")
    return sorted(seen, key=lambda _: rng.random())


class _Client:
    """One keep-alive connection; ``get`` returns (status, seconds)."""

    def __init__(self, host: str, port: int):
        self.conn = http.client.HTTPConnection(host, port, timeout=120)

    def get(self, path: str) -> tuple[int, float]:
        clock = time.perf_counter()
        self.conn.request("GET", path)
        r = self.conn.getresponse()
        r.read()
        return r.status, time.perf_counter() - clock

    def close(self):
        self.conn.close()


def _grid(client: _Client, ident: str) -> tuple[int, int]:
    """(side, scale) of the file's tile grid: its width, and grid pixels per input pixel (``/api/files``)."""
    client.conn.request("GET", "/api/files")
    f = next(f for f in json.loads(client.conn.getresponse().read()) if f["id"] == ident)
    return f["width"], f["scale"]


def _run_clients(host, port, paths: list[str], clients: int, deadline: float = math.inf):
    """Request ``paths`` from ``clients`` concurrent connections (each takes the next path); return (latencies,
    statuses, seconds, requests made)."""
    todo = iter(paths)
    lock = threading.Lock()
    latencies, statuses = [], []

    def work():
        client = _Client(host, port)
        try:
            while time.perf_counter() < deadline:
                with lock:
                    path = next(todo, None)
                if path is None:
                    return
                try:
                    status, seconds = client.get(path)
                except (OSError, http.client.HTTPException):
                    status, seconds = 0, 0.0
                    client.close()
                    client = _Client(host, port)
                with lock:
                    latencies.append(seconds)
                    statuses.append(status)
        finally:
            client.close()

    clock = time.perf_counter()
    threads = [threading.Thread(target=work) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return latencies, statuses, time.perf_counter() - clock


@click.command()
@click.argument("dfield", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--tiles", "n_tiles", type=click.IntRange(5, 10000), default=60, show_default=True,
              help="Distinct tiles timed cold, then warm.")
@click.option("--clients", default="1,2,16", show_default=True, help="Concurrent clients of the throughput runs.")
@click.option("--throughput-tiles", type=click.IntRange(1), default=48, show_default=True,
              help="Tiles (all rendered) per throughput run.")
@click.option("--threads", type=click.IntRange(1, 256), default=1, show_default=True,
              help="The server's --threads: tiles rendered at once.")
@click.option("--cache-mb", type=click.FloatRange(0), default=16, show_default=True, help="The server's --cache-mb.")
@click.option("--load-requests", type=click.IntRange(0, 100000), default=1000, show_default=True,
              help="Requests of the load test (0 skips it).")
@click.option("--load-clients", type=click.IntRange(1, 256), default=16, show_default=True)
@click.option("--load-pool", type=click.IntRange(1), default=300, show_default=True,
              help="Distinct tiles the load test draws from.")
@click.option("--time-limit", type=click.FloatRange(1), default=300, show_default=True,
              help="Seconds after which the load test stops issuing requests.")
@click.option("--seed", type=int, default=0, show_default=True)
@json_option
@quiet_option
def command(dfield, n_tiles, clients, throughput_tiles, threads, cache_mb, load_requests, load_clients, load_pool,
            time_limit, seed, json_path, quiet):
    """Time dfc serve on DFIELD (default: the shipped samples/sample.dfield) over HTTP on 127.0.0.1: tile latency
    cold and warm, throughput with 1, 2 and 16 clients, and a load test of 1,000 requests from 16 clients with the
    server's memory against its cache bound."""
    try:
        counts = [int(c) for c in clients.split(",")]
        assert counts and all(1 <= c <= 256 for c in counts)
    except (ValueError, AssertionError):
        raise click.BadParameter(f"expected comma-separated counts in 1..256, got {clients!r}",
                                 param_hint="'--clients'") from None
    err = stdout_taken(json_path)
    dfield = Path(dfield or SAMPLES / "sample.dfield")
    rng = random.Random(seed)
    cmd = [sys.executable, "-m", "dfc", "serve", str(dfield), "--port", "0", "-q", "--threads", str(threads),
           "--cache-mb", str(cache_mb)]
    clock = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        if not first.startswith("dfc serve: http://"):
            raise click.ClickException(f"dfc serve did not start ({first.strip() or 'no output'})")
        ident = proc.stdout.readline().split("/iiif/")[1].split("/")[0]
        host, port = first.split("//")[1].split("/")[0].rsplit(":", 1)
        port = int(port)
        figures = _measure(host, port, ident, proc.pid, rng, clock, n_tiles, counts, throughput_tiles, load_requests,
                           load_clients, load_pool, time_limit)
    finally:
        proc.terminate()
        proc.wait(30)
    figures.update(file=str(dfield), threads=threads, cache_mb=cache_mb)
    figures["latency"].update(_in_process(dfield, figures.pop("cold_paths")))
    click.echo(f"dfc serve {dfield.name} on 127.0.0.1, --threads {threads}, --cache-mb {cache_mb:g}: 256x256 PNG "
               f"tiles", err=err)
    click.echo(latency_table(figures["latency"]), err=err)
    click.echo("throughput (every tile rendered):", err=err)
    click.echo(throughput_table(figures["throughput"]), err=err)
    load = figures.get("load")
    if load:
        click.echo(f"load test: {load['requests']} requests from {load['clients']} clients ({load['pool']} distinct "
                   f"tiles) in {load['seconds']:.1f} s, {load['requests'] / load['seconds']:.1f} tiles/s, "
                   f"{load['errors']} errors; server memory {load['rss_before_mb']:.0f} MB before, peak "
                   f"{load['peak_mb']:.0f} MB (+{load['peak_mb'] - load['rss_before_mb']:.0f} MB; cache bound "
                   f"{cache_mb:g} MB)", err=err)
    if json_path:
        write_json(json_path, figures)


def _in_process(dfield: Path, paths: list[str]) -> dict:
    """Latency rows of rendering and encoding ``paths``' tiles in this process on one thread (model warmed up by one
    tile first): wall time, and the thread's CPU time, which is the wall time an idle core would take (on a busy
    machine the wall time also counts the waits for a core)."""
    import torch

    from ...codec import load
    from ...serve.iiif import parse_image_request
    from ...tiles import encode_tile, render_tile, tile_grid

    torch.set_num_threads(1)
    model = load(dfield)
    grid = tile_grid(model)
    wall, cpu = [], []
    for k, path in enumerate([paths[0], *paths]):
        request = parse_image_request(*path.split("/")[3:], grid.width, grid.height)
        clock, clock_cpu = time.perf_counter(), time.thread_time()
        encode_tile(render_tile(model, request.region, request.size, grid=grid), request.fmt)
        if k:
            wall.append(time.perf_counter() - clock)
            cpu.append(time.thread_time() - clock_cpu)
    return {"same tiles in-process (wall)": latency_summary(wall),
            "same tiles in-process (CPU time)": latency_summary(cpu)}


def _measure(host, port, ident, pid, rng, started, n_tiles, counts, throughput_tiles, load_requests, load_clients,
             load_pool, time_limit) -> dict:
    client = _Client(host, port)
    side, scale = _grid(client, ident)
    paths = tile_paths(ident, side, n_tiles + len(counts) * throughput_tiles + 1, rng)
    first, cold_paths, rest = paths[0], paths[1:n_tiles + 1], paths[n_tiles + 1:]
    status, first_s = client.get(first)
    if status != 200:
        raise click.ClickException(f"the first tile request failed with HTTP {status}")
    start_to_first = time.perf_counter() - started
    cold = [client.get(p)[1] for p in cold_paths]
    warm = [client.get(p)[1] for p in cold_paths]
    at_input = tile_paths(ident, side, min(n_tiles, math.ceil(side / (TILE * scale)) ** 2), rng, deepest=scale,
                          coarsest=scale)
    coarse = [client.get(p)[1] for p in at_input]
    client.close()
    latency = {"first tile after start": latency_summary([first_s]),
               "beyond the input, rendered (cold)": latency_summary(cold),
               "beyond the input, cached (warm)": latency_summary(warm),
               "at the input's resolution (cold)": latency_summary(coarse)}
    throughput = []
    for k, c in enumerate(counts):
        batch = rest[k * throughput_tiles:(k + 1) * throughput_tiles]
        _, statuses, seconds = _run_clients(host, port, batch, c)
        throughput.append({"clients": c, "tiles": len(batch), "seconds": seconds,
                           "errors": sum(s != 200 for s in statuses)})
    figures = {"cold_paths": cold_paths, "grid_side": side, "grid_scale": scale,
               "start_to_first_tile_s": start_to_first, "latency": latency,
               "throughput": throughput}
    if load_requests:
        pool = tile_paths(ident, side, load_pool, random.Random(rng.random()))
        requests = [rng.choice(pool) for _ in range(load_requests)]
        before = _status(pid, "VmRSS:")
        peak = [before]
        done = threading.Event()

        def watch():
            while not done.is_set():
                peak[0] = max(peak[0], _status(pid, "VmRSS:"))
                time.sleep(0.05)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            latencies, statuses, seconds = _run_clients(host, port, requests, load_clients,
                                                        time.perf_counter() + time_limit)
        finally:
            done.set()
            watcher.join()
        figures["load"] = {"requests": len(statuses), "asked": load_requests, "clients": load_clients,
                           "pool": load_pool, "seconds": seconds, "errors": sum(s != 200 for s in statuses),
                           "latency": latency_summary(latencies), "rss_before_mb": before,
                           "peak_mb": max(peak[0], _status(pid, "VmRSS:"))}
    return figures
