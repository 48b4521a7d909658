"""The install command named for a missing extra matches how latticeopt was installed."""

from __future__ import annotations

import sys

import pytest

from latticeopt import _extras
from latticeopt._extras import MissingExtraError, install_command, require_extra


def test_from_a_clone_the_command_is_an_editable_install(monkeypatch, tmp_path):
    root = _extras.source_checkout()
    assert root is not None and (root / "latticeopt" / "_extras.py").exists()  # the tests run from a clone
    monkeypatch.chdir(root)
    assert install_command("learn") == 'pip install -e ".[learn]"'
    monkeypatch.chdir(tmp_path)  # elsewhere: the clone's path instead of "."
    assert install_command("distributed") == f'pip install -e "{root}[distributed]"'


def test_from_a_wheel_the_command_names_the_package(monkeypatch):
    monkeypatch.setattr(_extras, "source_checkout", lambda: None)
    assert install_command("learn") == 'pip install "latticeopt[learn]"'


def test_require_extra_names_the_flag_the_package_and_the_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(MissingExtraError) as info:
        require_extra("distributed", "a dask cluster", name="--backend dask")
    text = str(info.value)
    assert text == f"--backend dask: dask.distributed is not installed (a dask cluster): run " \
                   f"`{install_command('distributed')}`"
    assert info.value.name == "--backend dask" and "\n" not in text


def test_require_extra_checks_only_the_modules_asked_for(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)
    pytest.importorskip("skimage")
    require_extra("learn", "SSIM", modules=("skimage",))  # torch missing does not matter here
    with pytest.raises(MissingExtraError, match="PyTorch is not installed"):
        require_extra("learn", "training")
