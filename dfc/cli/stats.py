"""``dfc stats IN.dfield [--json]``: mesh, parameter and byte statistics of a file (no torch needed)."""

from __future__ import annotations

import click

from .options import quiet_option, stdin_file, write_json


def file_stats(path) -> dict:
    """The statistics ``dfc stats`` prints, as a JSON-able dict (the paper's Table 1 and more)."""
    from ..io.container import read_dfield_info

    info = read_dfield_info(path, with_mesh=True)
    header, feat, m, mesh = info["header"], info["features"], info["mesh"], info["decoded_mesh"]
    encoder = header.get("encoder", {})
    pixels = encoder.get("pixels")
    times = header["times"]
    return {
        "file_bytes": info["file_bytes"],
        "container_version": ".".join(map(str, info["container_version"])),
        "content_version": ".".join(map(str, info["content_version"])),
        "domain": header["domain"],
        "channels": header["channels"],
        "value_transform": header["value_transform"],
        "value_map": ({"offset": header["value_offset"], "scale": header["value_scale"]}
                      if header["value_transform"] == "affine" else None),
        "time_axis": None if times is None else {"slices": len(times), "first": times[0], "last": times[-1]},
        "mesh": {"vertices": m["vertices"], "triangles": m["triangles"], "discontinuous_vertices": mesh.n_disc_vertices,
                 "discontinuous_edges": m["disc_edges"], "curved_triangles": m["curves"],
                 "encoding": m["encoding"], "bits": m["bits"],
                 "free_vertex_bits": m["bits"] - m["shift"] if m["encoding"] == "derived" else None,
                 "topology_chunk": m["topology"], "control_points": m["control_points"]},
        "parameters": {"features": feat["slices"] * feat["rows"] * feat["width"], "feature_rows": feat["rows"],
                       "feature_dim": feat["width"], "feature_bits": feat["bits"], "feature_coding": feat["coding"],
                       "mlp": info["mlp"]["parameters"], "mlp_weight_bits": info["mlp"]["weight_bits"] or None},
        "model": header["model"],
        "chunk_bytes": info["chunks"],
        "residual": info["residual"],
        "bits_per_pixel": None if not pixels else 8.0 * info["file_bytes"] / pixels,
        "encoder": encoder,
    }


@click.command()
@click.argument("input_path", metavar="IN", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("--json", "json_path", is_flag=False, flag_value="-", type=click.Path(dir_okay=False, allow_dash=True),
              help="Write the statistics as one JSON object to this file, or with no file (or -) to standard output "
                   "instead of the table.")
@quiet_option
def command(input_path, json_path, quiet):
    """Print the mesh, parameter and byte statistics of IN (- reads standard input): triangles, vertices,
    discontinuous vertices, curved triangles, how the curves' control points are stored, feature and MLP parameters,
    bytes per chunk, bits per pixel of the encoded input, versions."""
    with stdin_file(input_path, "stdin.dfield") as path:
        s = file_stats(path)
    if json_path:
        write_json(json_path, s)
        if json_path == "-":
            return
    m, p = s["mesh"], s["parameters"]
    rows = [
        ("file", f"{s['file_bytes']} bytes, container {s['container_version']}, content {s['content_version']}"),
        ("domain", ", ".join(f"{v:g}" for v in s["domain"])),
        ("channels", f"{', '.join(s['channels'])} ({s['value_transform']})"),
        *([("units", "value = offset + scale · output; offset " + ", ".join(map(repr, s["value_map"]["offset"])) +
                    "; scale " + ", ".join(map(repr, s["value_map"]["scale"])))] if s["value_map"] else []),
        ("time axis", "none" if s["time_axis"] is None else
         f"{s['time_axis']['slices']} slices, t = {s['time_axis']['first']:g} .. {s['time_axis']['last']:g}"),
        ("vertices", m["vertices"]), ("triangles", m["triangles"]),
        ("discontinuous vertices", m["discontinuous_vertices"]), ("discontinuous edges", m["discontinuous_edges"]),
        ("curved triangles", m["curved_triangles"]),
        ("mesh encoding", f"{m['encoding']}" + (f", {m['bits']} bits" if m["encoding"] == "draco" else "")
         + (f", {m['bits']} bits on the curves, {m['free_vertex_bits']} elsewhere, triangles derived"
            if m["encoding"] == "derived" else "")),
        ("curve control points", f"{m['control_points']} ({m['topology_chunk']})"),
        ("feature parameters", f"{p['features']} ({p['feature_rows']} rows x {p['feature_dim']}, {p['feature_bits']} bits, "
                               f"{p['feature_coding']})"),
        ("MLP parameters", f"{p['mlp']} (" + ("float16" if not p["mlp_weight_bits"] else
                                               f"{'/'.join(map(str, p['mlp_weight_bits']))}-bit weights") + ")"),
        *([("residual", "{width}x{height}, {channels} channels, AVIF {bits}-bit, added to the {}".format(
            "values" if s["residual"]["space"] == "values" else "tone-mapped values", **s["residual"]))]
          if s["residual"] else []),
        ("bits per pixel", "n/a" if s["bits_per_pixel"] is None else f"{s['bits_per_pixel']:.3f}"),
    ]
    rows += [(f"chunk {name}", f"{size} bytes") for name, size in s["chunk_bytes"].items()]
    found = s["encoder"].get("curves")
    if found:
        settings = found.get("settings")  # earlier files recorded the extractor's settings, defaults included
        rows.append(("curves", f"{found['curves']} curves ({found['pieces']} pieces) {found['extracted']}"
                               + (f", pixel filter {found['pixel_filter']}" if found.get("pixel_filter") else "")
                               + (", settings " + ", ".join(f"{k}={v}" for k, v in settings.items()) if settings else "")))
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        click.echo(f"{key:<{width}}  {value}")
