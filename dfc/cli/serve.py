"""``dfc serve FILE.dfield … [--host 127.0.0.1] [--port 8000] [--threads N] [--cache-mb M] [--compare IMAGE …]``: the
IIIF tile server and viewer of ``dfc.serve``, in the foreground until Ctrl-C or SIGTERM."""

from __future__ import annotations

import ipaddress
import os
import sys
from typing import NoReturn

import click

from .options import (
    THREADS_ENV,
    json_option,
    quiet_option,
    stdout_taken,
    warn,
    write_json,
)

LOOPBACK = ("localhost",)


def serve_options(f):
    """The options ``dfc serve`` and ``dfc view`` share."""
    for option in reversed([
        click.option("--compare", "compare", multiple=True, type=click.Path(exists=True, dir_okay=False),
                     help="An input raster (EXR, PNG, JPEG) shown beside the file, upsampled bicubically; repeat it "
                          "to pair one with each FILE in order."),
        click.option("--threads", type=click.IntRange(1, 256), default=1, show_default=True, envvar=THREADS_ENV,
                     show_envvar=True, help="Tiles rendered at once, each on one CPU thread."),
        click.option("--cache-mb", type=click.FloatRange(0, 1 << 20), default=256, show_default=True,
                     help="Bound of the cache of encoded tiles, in MB."),
        click.option("--levels-beyond", type=click.IntRange(0, 20), default=10, show_default=True,
                     help="Pyramid levels past the input's resolution: 10 zooms 1024x deeper."),
        json_option,
        quiet_option,
    ]):
        f = option(f)
    return f


@click.command()
@click.argument("files", metavar="FILE.dfield...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False))
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on; any other than a loopback address is warned about.")
@click.option("--port", type=click.IntRange(0, 65535), default=8000, show_default=True, help="Port (0: a free one).")
@serve_options
def command(files, host, port, compare, threads, cache_mb, levels_beyond, json_path, quiet):
    """Serve FILE.dfield… as IIIF Image API 3.0 images (/iiif/ID/info.json; level 1 with pct: regions and sizes,
    !w,h, ^ upscaling, PNG, JPEG and float EXR) with a deep-zoom viewer at /: tiles rendered on demand, any depth,
    kept in a bounded cache. Only the named files are served. Stops on Ctrl-C or SIGTERM. --json writes the URL and the
    files' identifiers once it listens."""
    server = start(files, compare, host, port, threads, cache_mb, levels_beyond, json_path, quiet)
    run(server, quiet)


def start(files, compare, host, port, threads, cache_mb, levels_beyond, json_path, quiet):
    """Load the files, bind the server and print its URL and the files' identifiers (stdout, or standard error when
    ``json_path`` is ``-``; ``json_path`` also gets them as JSON); the server, not yet serving."""
    import torch

    from ..serve.server import App, make_server
    from ..serve.sources import FieldSource, RasterSource, identifiers

    if len(compare) > len(files):
        raise click.UsageError(f"{len(compare)} --compare images for {len(files)} files: give at most one per file")
    if not _loopback(host):
        warn(f"listening on {host}: anyone who can reach this address can read the served files at any zoom "
             "(the default 127.0.0.1 keeps them on this machine)", quiet)
    torch.set_num_threads(1)
    pairs = []
    idents = identifiers(files)
    for ident, path, image in zip(idents, files, list(compare) + [None] * len(files)):
        source = FieldSource(ident, path, levels_beyond=levels_beyond)
        pairs.append((source, RasterSource(_compare_id(ident, idents), image, source) if image else None))
    try:
        server = make_server(App(pairs, cache_bytes=int(cache_mb * 1e6), threads=threads), host, port, quiet=quiet)
    except OSError as e:
        raise click.ClickException(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
    bound_host, bound_port = server.server_address[:2]
    shown = f"[{bound_host}]" if ":" in bound_host else bound_host
    server.url = f"http://{shown}:{bound_port}/"
    if json_path:
        write_json(json_path, {"url": server.url, "files": [
            {"id": s.ident, "file": path, "info": f"{server.url}iiif/{s.ident}/info.json",
             "compare": None if r is None else f"{server.url}iiif/{r.ident}/info.json"}
            for (s, r), path in zip(pairs, files)]})
    err = stdout_taken(json_path)
    click.echo(f"dfc serve: {server.url}  (Ctrl-C stops)", err=err)
    for source, raster in pairs:
        also = f", compared with {raster.name}" if raster else ""
        click.echo(f"  {source.name}: {server.url}iiif/{source.ident}/info.json{also}", err=err)
    sys.stdout.flush()
    return server


def run(server, quiet: bool) -> NoReturn:
    """Serve until Ctrl-C or SIGTERM (which ``dfc.cli.main`` turns into SystemExit), close the socket, stop the render
    pool, and end the process with status 0.

    The process ends with ``os._exit`` once its streams are flushed: nothing is left to write or remove then, and
    the interpreter's own finalisation aborted about one stop in twenty ("terminate called without an active
    exception", status -6, from a C++ static destructor of an extension library, with no Python thread left)."""
    try:
        server.serve_forever(poll_interval=0.25)
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        server.server_close()
        server.app.close()
    if not quiet:
        click.echo("dfc serve: stopped", err=True)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def _compare_id(ident: str, taken: list[str]) -> str:
    """``ident-compare``, numbered when a served file already has that identifier."""
    candidate, k = f"{ident}-compare", 2
    while candidate in taken:
        candidate, k = f"{ident}-compare-{k}", k + 1
    return candidate


def _loopback(host: str) -> bool:
    if host in LOOPBACK:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
