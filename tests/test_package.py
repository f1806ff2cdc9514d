"""The ``dfc`` package's names: ``dfc.render`` is the module whether or not it was imported first, the render
function is ``dfc.render_model``, and the lazily imported names resolve."""

import subprocess
import sys

import dfc


def test_render_is_the_module_before_and_after_it_is_imported():
    code = ("import dfc, types; first = dfc.render; import dfc.render as m; "
            "assert isinstance(first, types.ModuleType) and first is m is dfc.render; "
            "assert dfc.render_model is m.render; print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_lazy_names_resolve():
    for name in dfc.__all__:
        assert getattr(dfc, name) is not None, name
    assert dfc.read_curves.__module__ == "dfc.geometry.sources"
    assert dfc.EncodeSettings(steps=1000).steps == 1000
