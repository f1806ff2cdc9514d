"""``dfc view FILE.dfield [--compare IMAGE]``: ``dfc serve`` on a free local port, with the viewer opened in the
browser."""

from __future__ import annotations

import click

from .serve import run, serve_options, start


@click.command()
@click.argument("files", metavar="FILE.dfield...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False))
@click.option("--no-browser", is_flag=True, help="Print the viewer's URL without opening a browser.")
@serve_options
def command(files, no_browser, compare, threads, cache_mb, levels_beyond, json_path, quiet):
    """Look at FILE.dfield… at any zoom: serve them on 127.0.0.1 (a free port) and open the viewer in the browser
    (with --compare: the side-by-side view). Stops on Ctrl-C."""
    import webbrowser

    server = start(files, compare, "127.0.0.1", 0, threads, cache_mb, levels_beyond, json_path, quiet)
    url = server.url + ("?compare=1" if compare else "")
    if not no_browser and not webbrowser.open(url):
        click.echo(f"dfc view: no browser found; open {url}", err=True)
    run(server, quiet)
