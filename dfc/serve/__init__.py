"""``dfc serve`` and ``dfc view``: a IIIF Image API 3.0 tile server for ``.dfield`` files and the deep-zoom viewer
page it serves (OpenSeadragon, shipped in ``static/`` with its licence, so the page works offline)."""
