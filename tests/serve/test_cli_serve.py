"""``dfc serve`` and ``dfc view`` as processes: they start on a free port, serve, and stop cleanly on SIGINT and
SIGTERM; bad input is one error line."""

import http.client
import json
import os
import signal
import subprocess
import sys

import pytest

from dfc.cli.serve import _compare_id, _loopback

from ..cli.test_cli import assert_one_line_error, run
from ..conftest import SAMPLES

SAMPLE = SAMPLES / "sample.dfield"


def _default_sigint() -> None:
    """In the child before it runs: SIGINT's default action, as from a terminal. A test run started in the
    background of a non-interactive shell (``pytest &``) ignores SIGINT, the server would inherit that, and
    Python installs no KeyboardInterrupt handler for an ignored SIGINT: the server would not stop."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(*args):
    """A ``dfc`` server process started with ``args`` and its URL's (host, port), once it listens (with
    ``faulthandler`` on: SIGABRT prints every thread's stack, ``stacks_of``)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONFAULTHANDLER": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "dfc", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, preexec_fn=_default_sigint)
    line = proc.stdout.readline()
    assert line.startswith("dfc serve: http://127.0.0.1:"), (line, proc.stderr.read() if proc.poll() else "")
    host, port = line.split("//")[1].split("/")[0].split(":")
    return proc, host, int(port)


def stacks_of(proc) -> str:
    """The end of a hung server's standard error after SIGABRT: ``faulthandler``'s stacks of its threads."""
    proc.send_signal(signal.SIGABRT)
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        return "(no stacks: the process did not end on SIGABRT)"
    return err[-4000:]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_stops_cleanly(sig):
    proc, host, port = start("serve", SAMPLE, "--port", "0", "--cache-mb", "1")
    try:
        conn = http.client.HTTPConnection(host, port, timeout=60)
        conn.request("GET", "/iiif/sample/full/64,/0/default.png")
        r = conn.getresponse()
        assert r.status == 200 and r.read()[:4] == b"\x89PNG"
        conn.close()
        proc.send_signal(sig)
        try:
            code = proc.wait(30)
        except subprocess.TimeoutExpired:
            pytest.fail(f"still running 30 s after {sig!r}; its threads:\n{stacks_of(proc)}")
        assert code == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read()
    assert "Traceback" not in err and "dfc serve: stopped" in err


def test_view_without_browser_serves_the_viewer(tmp_path):
    record = tmp_path / "view.json"
    proc, host, port = start("view", SAMPLE, "--no-browser", "--compare", SAMPLES / "sample.exr", "-q", "--json",
                             record)
    try:
        figures = json.loads(record.read_text())
        assert figures["url"] == f"http://{host}:{port}/" and figures["files"][0]["id"] == "sample"
        assert figures["files"][0]["compare"].endswith("/iiif/sample-compare/info.json")
        conn = http.client.HTTPConnection(host, port, timeout=60)
        conn.request("GET", "/api/files")
        r = conn.getresponse()
        assert r.status == 200 and b'"sample-compare"' in r.read()
        conn.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0


def test_serve_refuses_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.dfield"
    bad.write_bytes(b"not a dfield file")
    code, _, err = run(["serve", bad, "--port", "0"], capsys)
    assert_one_line_error(code, err, "bad.dfield")
    code, _, err = run(["serve", SAMPLE, "--compare", SAMPLES / "sample.exr", "--compare", SAMPLES / "sample.exr"],
                       capsys)
    assert_one_line_error(code, err, "at most one per file")


def test_loopback_addresses():
    assert _loopback("127.0.0.1") and _loopback("::1") and _loopback("localhost") and _loopback("127.8.0.1")
    assert not _loopback("0.0.0.0") and not _loopback("192.168.1.2") and not _loopback("example.org")


def test_compare_identifiers_never_shadow_a_file():
    assert _compare_id("a", ["a", "b"]) == "a-compare"
    assert _compare_id("a", ["a", "a-compare", "a-compare-2"]) == "a-compare-3"
