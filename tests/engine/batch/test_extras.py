"""Without the scale extra the batch package says how to install it; the engine core does not need it."""

from __future__ import annotations

import builtins
import subprocess
import sys

import pytest

from lfm_studio.engine.batch import extras


def test_missing_package_names_the_install_line(monkeypatch):
    real_import = builtins.__import__

    def no_zarr(name, *args, **kwargs):
        if name == "zarr" or name.startswith("zarr."):
            raise ModuleNotFoundError("No module named 'zarr'")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "zarr", raising=False)
    monkeypatch.setattr(builtins, "__import__", no_zarr)
    with pytest.raises(extras.MissingExtraError, match=r'zarr .*pip install "lfm-studio\[scale\]"'):
        extras.require_scale()
    assert issubclass(extras.MissingExtraError, ImportError)


def test_engine_core_imports_without_dask_or_zarr():
    code = (
        "import sys\n"
        "for name in ('dask', 'distributed', 'zarr', 'ome_zarr'): sys.modules[name] = None\n"
        "import lfm_studio.engine, lfm_studio.engine.simulation, lfm_studio.engine.reconstruct\n"
        "try:\n    import lfm_studio.engine.batch\nexcept ImportError as e:\n    print(type(e).__name__, e)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.startswith("MissingExtraError") and 'pip install "lfm-studio[scale]"' in out.stdout
