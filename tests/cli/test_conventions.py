"""Command-line conventions: threads, - for standard input and output, --json -, -q, progress bars only on a
terminal, the decode plan and its disk-space guard, one-line warnings, one-line errors from damaged EXRs with the
OpenEXR library's own output silenced, output errors that name the requested file."""

import io
import json
import os
import shutil
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest
import torch

from dfc.cli import main
from dfc.io.image import read_image, write_png

from ..conftest import SAMPLES
from .test_cli import assert_one_line_error, run

DFIELD = SAMPLES / "sample.dfield"


def _stdin(monkeypatch, data: bytes):
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(data)))


class _BinaryStdout:
    """Standard output whose bytes a test reads back (click writes binary output to ``sys.stdout.buffer``)."""

    def __init__(self):
        self.buffer = io.BytesIO()
        self.text = io.TextIOWrapper(self.buffer, write_through=True)

    def __getattr__(self, name):
        return getattr(self.text, name)


# ------------------------------------------------------------------------------------------------ threads
def test_threads_option_and_environment(monkeypatch, tmp_path, capsys):
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas() -> set[int]:  # the thread counts of every BLAS loaded (numpy's and SciPy's OpenBLAS)
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    before, blas_before = torch.get_num_threads(), max(blas())
    try:
        code, _, err = run(["decode", DFIELD, "-o", tmp_path / "a.png", "--size", "8x8", "--threads", "2", "-q"],
                           capsys)
        assert code == 0, err
        assert torch.get_num_threads() == 2 and blas() == {2}
        monkeypatch.setenv("DFC_THREADS", "1")
        code, _, err = run(["decode", DFIELD, "-o", tmp_path / "b.png", "--size", "8x8", "-q"], capsys)
        assert code == 0, err
        assert torch.get_num_threads() == 1 and blas() == {1}  # idle BLAS threads spin beside other programs
        code, _, err = run(["decode", DFIELD, "-o", tmp_path / "c.png", "--threads", "0"], capsys)
        assert_one_line_error(code, err, "--threads")
        for cmd in ("encode", "decode", "zoom", "solve", "bench"):
            code, out, _ = run([cmd, "--help"], capsys)
            assert "--threads" in out and "DFC_THREADS" in out
    finally:
        torch.set_num_threads(before)
        threadpool_limits(blas_before, user_api="blas")


def test_entry_point_lets_openmp_threads_sleep(monkeypatch, capsys):
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    run(["--version"], capsys)
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")  # a user's own setting is kept
    run(["--version"], capsys)
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"


# ------------------------------------------------------------------------------------------------ - and --json -
def test_decode_to_standard_output(monkeypatch, tmp_path, capsys):
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "file.png", "--size", "40x30", "-q"], capsys)
    assert code == 0, err
    for fmt in ("png", "exr"):
        stdout = _BinaryStdout()
        monkeypatch.setattr(sys, "stdout", stdout)
        with _no_exit():
            main(["decode", str(DFIELD), "-o", "-", "--format", fmt, "--size", "40x30", "-q"])
        monkeypatch.undo()
        data = stdout.buffer.getvalue()
        assert data[:4] == (b"\x89PNG" if fmt == "png" else b"\x76\x2f\x31\x01")
        (tmp_path / f"piped.{fmt}").write_bytes(data)
        piped = read_image(tmp_path / f"piped.{fmt}").pixels
        assert piped.shape == (30, 40, 3)
        if fmt == "png":
            np.testing.assert_array_equal(piped, read_image(tmp_path / "file.png").pixels)
    code, _, err = run(["decode", DFIELD, "-o", "-"], capsys)
    assert_one_line_error(code, err, "--format")
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "x.png", "--format", "exr"], capsys)
    assert_one_line_error(code, err, "contradicts")


class _no_exit:
    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is SystemExit and value.code in (0, None):
            return True
        return False


def test_curves_and_files_from_standard_input(monkeypatch, tmp_path, capsys):
    _stdin(monkeypatch, (SAMPLES / "sample.json").read_bytes())
    code, out, err = run(["mesh", "-", "-o", tmp_path / "m.svg", "--json", "-"], capsys)
    assert code == 0, err
    figures = json.loads(out)  # standard output holds only the JSON; the text went to standard error
    assert figures["triangles"] > 0 and "triangles:" in err
    _stdin(monkeypatch, b'{"format": "dfc-curves/1", "domain": [0, 0, 1]}')
    code, _, err = run(["mesh", "-", "-o", tmp_path / "n.svg"], capsys)
    assert_one_line_error(code, err, "<stdin>")
    assert "dfc-stdin" not in err  # the temporary file is not named
    _stdin(monkeypatch, DFIELD.read_bytes())
    code, out, err = run(["stats", "-", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["file_bytes"] == DFIELD.stat().st_size
    code, _, err = run(["encode", "-", "--curves", "-", "-o", tmp_path / "o.dfield"], capsys)
    assert_one_line_error(code, err, "standard input")


def test_json_to_standard_output_not_to_a_file_named_dash(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(["decode", DFIELD, "-o", "z.exr", "--size", "16x16", "--json", "-", "-q"], capsys)
    assert code == 0, err
    record = json.loads(out)
    assert record["outputs"] == ["z.exr"] and record["size"] == [16, 16] and record["bytes"][0] > 0
    assert "wrote z.exr" in err and not (tmp_path / "-").exists()
    code, _, _ = run(["decode", DFIELD, "-o", "y.exr", "--size", "16x16", "--json", "y.json", "-q"], capsys)
    assert code == 0 and json.loads((tmp_path / "y.json").read_text())["outputs"] == ["y.exr"]


def test_every_command_has_quiet_and_json(capsys):
    from dfc.cli import COMMANDS

    for cmd in COMMANDS:
        code, out, _ = run([cmd, "--help"], capsys)
        if cmd == "benchmark":
            continue
        assert code == 0 and "--quiet" in out and "--json" in out, cmd
    for name in ("field", "decode", "mesh", "wos", "fem", "wave"):
        code, out, _ = run(["benchmark", name, "--help"], capsys)
        assert "--quiet" in out and "--json" in out and "standard output" in out, name


# ------------------------------------------------------------------------------------------------ progress
def test_progress_bars_only_on_a_terminal(monkeypatch):
    from dfc.cli.options import progress_bar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", io.StringIO())
    with progress_bar(10, "fit", quiet=False) as bar:
        assert bar.disable
    monkeypatch.setattr(sys, "stderr", Terminal())
    with progress_bar(10, "fit", quiet=False) as bar:
        assert not bar.disable
        bar.update(10)
    with progress_bar(10, "fit", quiet=True) as bar:
        assert bar.disable


# ------------------------------------------------------------------------------------------------ guards
def test_decode_plan_and_disk_space_guard(monkeypatch, tmp_path, capsys):
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "a.exr", "--size", "300x200"], capsys)
    assert code == 0, err
    plan = err.splitlines()[0]
    assert plan.startswith("decode: 300x200, 3 channels (R, G, B) to half EXR: at most ") and ("second" in plan
                                                                                               or " s" in plan)
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "q.exr", "--size", "300x200", "-q"], capsys)
    assert code == 0 and err == ""
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(10**9, 10**9 - 10**6, 10**6))
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "big.exr", "--size", "4096x4096"], capsys)
    assert_one_line_error(code, err, str(tmp_path / "big.exr"))
    assert "not enough free disk space" in err and "100.7 MB" in err and "1.0 MB are free" in err
    assert not (tmp_path / "big.exr").exists()


def test_float_png_is_refused(tmp_path, capsys):
    for cmd in (["decode", DFIELD], ["zoom", DFIELD, "--center", "100,100", "--zoom", "4"]):
        code, _, err = run([*cmd, "-o", tmp_path / "f.png", "--float"], capsys)
        assert_one_line_error(code, err, "--float applies to EXR output")
    assert not (tmp_path / "f.png").exists()


def test_windows_and_curves_outside_the_domain_warn(tmp_path, capsys):
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "w.exr", "--window", "300,300,400,400", "--size", "8x8"],
                       capsys)
    warnings = [ln for ln in err.splitlines() if ln.startswith("dfc: warning:")]
    assert code == 0 and len(warnings) == 1 and "entirely outside the domain" in warnings[0]
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "w.exr", "--window", "300,300,400,400", "--size", "8x8",
                        "-q"], capsys)
    assert code == 0 and err == ""
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "v.exr", "--window", "200,200,400,400", "--size", "8x8"],
                       capsys)
    assert "warning" not in err  # overlapping the domain is not outside it
    curves = json.loads((SAMPLES / "sample.json").read_text())
    curves["curves"].append({"name": "far away", "pieces": [{"type": "line", "points": [[300, 10], [400, 20]]}]})
    (tmp_path / "c.json").write_text(json.dumps(curves))
    code, _, err = run(["mesh", tmp_path / "c.json", "-o", tmp_path / "m.svg"], capsys)
    warnings = [ln for ln in err.splitlines() if ln.startswith("dfc: warning:")]
    assert code == 0 and len(warnings) == 1 and "1 curve entirely outside the domain" in warnings[0]
    assert "far away" in warnings[0]
    code, _, err = run(["mesh", tmp_path / "c.json", "-o", tmp_path / "m.svg", "-q"], capsys)
    assert code == 0 and "warning" not in err


def test_tiny_input_says_the_file_is_larger(tmp_path, capsys):
    write_png(tmp_path / "one.png", np.full((1, 1, 3), 0.5, np.float32))
    (tmp_path / "c.json").write_text('{"format": "dfc-curves/1", "domain": [0, 0, 1, 1], "curves": []}')
    code, out, err = run(["encode", tmp_path / "one.png", "--curves", tmp_path / "c.json", "-o", tmp_path / "o.dfield",
                          "--steps", "3", "--batch-size", "16"], capsys)
    assert code == 0, err
    notes = [ln for ln in err.splitlines() if ln.startswith("dfc: note:")]
    assert len(notes) == 1 and "larger than the input" in notes[0]
    assert (tmp_path / "o.dfield").stat().st_size < 2000 and "2 triangles" in out


def test_list_scenes_prints_one_summary_line_each(capsys):
    from dfc.bench.corpus import CASES
    from dfc.bench.scenes import SCENES, SUMMARIES

    assert set(SUMMARIES) == set(SCENES)
    code, out, _ = run(["bench", "--list-scenes"], capsys)
    lines = out.strip().splitlines()
    scenes = [ln for ln in lines if not ln.startswith("corpus case ")]
    cases = [ln.removeprefix("corpus case ").split(":")[0] for ln in lines if ln.startswith("corpus case ")]
    assert code == 0 and [ln.split()[0] for ln in scenes] == list(SCENES) and cases == list(CASES)
    for line in lines:
        assert "``" not in line and line.rstrip()[-1] not in ",(" and len(line) < 130


# ------------------------------------------------------------------------------------------------ errors
@pytest.mark.shared
def test_each_damaged_exr_gives_one_error_line_and_nothing_else(shared_data, tmp_path, capfd):
    """The OpenEXR library prints its own messages (fds 1 and 2) for 17 of these files; capfd sees the file
    descriptors, so a message that escaped the silencing would show here."""
    files = sorted(p for p in (shared_data / "exr" / "damaged").iterdir() if p.is_file() and p.suffix != ".rst")
    assert len(files) > 150
    for p in files:
        try:
            main(["encode", str(p), "--curves", str(SAMPLES / "sample.json"), "-o", str(tmp_path / "x.dfield")])
            code = 0
        except SystemExit as e:
            code = e.code
        captured = capfd.readouterr()
        assert captured.out == "", (p.name, captured.out)
        lines = captured.err.strip().splitlines()
        assert code == 1 and len(lines) == 1 and lines[0].startswith("dfc: error: "), (p.name, captured.err)
        assert p.name in lines[0]
    assert not (tmp_path / "x.dfield").exists()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
def test_output_errors_name_the_requested_file(capsys):
    code, _, err = run(["decode", DFIELD, "-o", "/proc/x.png", "--size", "8x8"], capsys)
    assert_one_line_error(code, err, "/proc/x.png")
    assert ".tmp" not in err


def test_atomic_write_errors_name_the_target(tmp_path):
    import errno

    from dfc.io.atomic import atomic_path

    target = tmp_path / "out.exr"
    with pytest.raises(OSError) as e:
        with atomic_path(target) as tmp:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert e.value.filename == str(target)
    with pytest.raises(OSError) as e:
        with atomic_path(target):
            raise OSError(errno.ENOSPC, "No space left on device")  # a write's error carries no file name
    assert e.value.filename == str(target)
    with pytest.raises(OSError) as e:
        with atomic_path(target):
            raise FileNotFoundError(2, "No such file", str(tmp_path / "input.exr"))  # another file's error
    assert e.value.filename == str(tmp_path / "input.exr")
    assert list(tmp_path.iterdir()) == []


def test_encode_from_standard_input_to_standard_output(monkeypatch, tmp_path, capsys):
    _stdin(monkeypatch, (SAMPLES / "sample.exr").read_bytes())
    stdout = _BinaryStdout()
    monkeypatch.setattr(sys, "stdout", stdout)
    with _no_exit():
        main(["encode", "-", "--curves", str(SAMPLES / "sample.json"), "-o", "-", "--steps", "2", "--batch-size",
              "256", "--max-triangles", "300", "-q"])
    monkeypatch.undo()
    blob = stdout.buffer.getvalue()
    assert blob[:4] == b"\x89DFL"
    err = capsys.readouterr().err
    assert f"wrote standard output: {len(blob)} bytes" in err  # the summary went to stderr
    (tmp_path / "piped.dfield").write_bytes(blob)
    code, out, _ = run(["stats", tmp_path / "piped.dfield", "--json"], capsys)
    assert code == 0 and json.loads(out)["encoder"]["input"] == "image 256x256"


def test_sample_set_summary_says_held_out_and_reference(tmp_path, capsys):
    from dfc.bench.scenes import sample_scene
    from dfc.io.samples import SampleSet, write_samples

    scene = sample_scene()
    rng = np.random.default_rng(1)
    xy = rng.random((4000, 2)) * 256
    noisy = (scene.value(xy) + rng.normal(0, 0.05, (len(xy), 3))).clip(0, 1).astype(np.float32)
    write_samples(tmp_path / "s.npz", SampleSet(xy, noisy, (0.0, 0.0, 256.0, 256.0), ["R", "G", "B"]))
    np.savez(tmp_path / "ref.npz", image=scene.render(32, 32, spp=1).astype(np.float32),
             domain=np.array([0.0, 0.0, 256.0, 256.0]))
    code, out, err = run(["encode", tmp_path / "s.npz", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "s.dfield",
                          "--steps", "20", "--batch-size", "1024", "--reference", tmp_path / "ref.npz", "--json",
                          tmp_path / "s.json", "-q"], capsys)
    assert code == 0, err
    assert "against 400 held-out samples (left out of the fit)" in out
    assert f"against the reference {tmp_path / 'ref.npz'}" in out
    record = json.loads((tmp_path / "s.json").read_text())
    assert record["heldout"] == 400 and record["psnr_reference"] is not None
    np.savez(tmp_path / "bad.npz", image=np.zeros((4, 4, 3), np.float32), domain=np.array([0.0, 0.0, 1.0, 1.0]))
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "t.dfield",
                        "--reference", tmp_path / "bad.npz"], capsys)
    assert_one_line_error(code, err, "domain")
    code, _, err = run(["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o",
                        tmp_path / "u.dfield", "--reference", tmp_path / "ref.npz"], capsys)
    assert_one_line_error(code, err, "--reference applies to sample sets")


def test_sigterm_unwinds_once(monkeypatch):
    """A second SIGTERM while the first one unwinds (exit handlers included) is ignored, not a traceback."""
    import signal

    from dfc.cli import _terminate

    monkeypatch.setattr(signal, "signal", lambda signum, handler: seen.append((signum, handler)))
    seen = []
    with pytest.raises(SystemExit) as exit_info:
        _terminate(signal.SIGTERM, None)
    assert exit_info.value.code == 128 + signal.SIGTERM
    assert seen == [(signal.SIGTERM, signal.SIG_IGN)]


def test_sigterm_after_the_command_ends_the_process_without_a_traceback():
    """A launcher stopping a rank that is already exiting: a SIGTERM that arrives in an exit handler, after the
    command ended, ends the process by the signal instead of raising inside the handler (a traceback)."""
    import signal

    script = ("import atexit, os, signal, time\n"
              "from dfc.cli import main\n"
              "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGTERM), time.sleep(5)))\n"
              "main(['--version'])\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == -signal.SIGTERM
