"""The package's face: the names ``from imm_gym import *`` gives and the version it reports."""

from __future__ import annotations

import importlib.metadata
import inspect

import imm_gym


def test_every_public_name_the_package_holds_is_exported() -> None:
    """``__all__`` is every public name imported into ``imm_gym`` (its submodules aside), no
    more and no fewer, and each is there."""
    public = {
        name
        for name, value in vars(imm_gym).items()
        if not name.startswith("_") and not inspect.ismodule(value)
    }
    assert set(imm_gym.__all__) == public | {"__version__"}
    assert len(imm_gym.__all__) == len(set(imm_gym.__all__))
    namespace: dict[str, object] = {}
    exec("from imm_gym import *", namespace)
    assert public <= set(namespace)


def test_the_version_is_the_installed_distribution_s() -> None:
    """``imm_gym.__version__`` (what results record as the package's version) is the version
    pyproject.toml gives the installed distribution."""
    assert imm_gym.__version__ == importlib.metadata.version("imm_gym")
