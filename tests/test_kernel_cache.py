"""imm_gym.kernel_cache: numba's caches dropped when the sources compiled into them change, kept
otherwise; on a package laid out in a temporary directory."""

from __future__ import annotations

from pathlib import Path

import pytest

from imm_gym import kernel_cache
from imm_gym.kernel_cache import DIGEST_FILE, compiled_sources, refresh

FILES = {
    "__init__.py": "",
    "kernels.py": (
        "import numba\n\nfrom imm_gym.constants import LIMIT\nfrom imm_gym.sub import body\n"
    ),
    "constants.py": "LIMIT = 1.0\n",
    "sub/__init__.py": "",
    "sub/body.py": "from numba import njit\n",
    "cli.py": "from imm_gym.kernels import run  # no numba here\n",
    "docs.py": '"""Mentions numba in a docstring only."""\n',
}


@pytest.fixture(autouse=True)
def _no_numba_cache_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    """``refresh`` reads ``NUMBA_CACHE_DIR`` by default: unset it, so that a test neither depends
    on the caller's cache folder nor writes the temporary package's digest into it."""
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)


@pytest.fixture
def package(tmp_path: Path) -> Path:
    root = tmp_path / "imm_gym"
    for name, text in FILES.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def _caches(root: Path) -> list[Path]:
    made = []
    for directory in (root / "__pycache__", root / "sub" / "__pycache__"):
        directory.mkdir(exist_ok=True)
        for name in ("kernels.run-10.py311.nbi", "kernels.run-10.py311.nbc"):
            (directory / name).write_text("machine code")
            made.append(directory / name)
    (root / "__pycache__" / "kernels.cpython-311.pyc").write_text("bytecode")
    return made


def test_the_sources_are_the_numba_modules_and_what_they_import(package: Path) -> None:
    names = [p.relative_to(package).as_posix() for p in compiled_sources(package)]
    assert names == ["constants.py", "kernels.py", "sub/__init__.py", "sub/body.py"]


def test_every_import_form_of_a_package_module_is_followed(package: Path) -> None:
    """A module imported from the package (``from imm_gym import a``), a submodule imported from
    a subpackage (``from imm_gym.sub import b``: ``sub/b.py``, not only ``sub/__init__.py``), an
    indented import, names in parentheses (a comment with a ``)`` among them) or over continued
    lines and several modules on one ``import`` line are compiled sources."""
    (package / "kernels.py").write_text(
        "import numba\n"
        "import os, imm_gym.plain as p, imm_gym.second_plain\n"
        "from imm_gym import constants\n"
        "from imm_gym.sub import more as m, body  # a comment\n"
        "from imm_gym.deep import (\n    first,  # see f(x)\n    second,\n)\n"
        "from imm_gym.deep import LIMIT, \\\n    third\n"
        "def late():\n    from imm_gym.lazy import value\n"
    )
    for name in ("sub/more.py", "deep/__init__.py", "deep/first.py", "deep/second.py",
                 "deep/third.py", "lazy.py", "unused.py", "plain.py", "second_plain.py"):
        (package / name).parent.mkdir(exist_ok=True)
        (package / name).write_text("VALUE = 1.0\n")
    names = [p.relative_to(package).as_posix() for p in compiled_sources(package)]
    assert names == [
        "__init__.py", "constants.py", "deep/__init__.py", "deep/first.py", "deep/second.py",
        "deep/third.py", "kernels.py", "lazy.py", "plain.py", "second_plain.py",
        "sub/__init__.py", "sub/body.py", "sub/more.py",
    ]
    assert refresh(package)
    caches = _caches(package)
    assert not refresh(package)
    (package / "sub" / "more.py").write_text("VALUE = 2.0\n")
    assert refresh(package)
    assert not any(p.exists() for p in caches)


def test_caches_are_dropped_when_a_source_changes_and_kept_otherwise(package: Path) -> None:
    caches = _caches(package)
    assert refresh(package)  # no digest recorded yet: nothing known about these caches
    assert not any(p.exists() for p in caches)
    assert (package / "__pycache__" / "kernels.cpython-311.pyc").exists()
    caches = _caches(package)
    assert not refresh(package)
    assert all(p.exists() for p in caches)
    (package / "cli.py").write_text("# edited, compiles nothing\n")
    (package / "docs.py").write_text('"""numba, numba."""\n')
    assert not refresh(package)
    assert all(p.exists() for p in caches)
    (package / "constants.py").write_text("LIMIT = 2.0\n")  # a constant a kernel reads
    assert refresh(package)
    assert not any(p.exists() for p in caches)
    recorded = (package / DIGEST_FILE).read_text()
    assert recorded == kernel_cache.source_digest(package)


def test_an_unwritable_package_is_left_alone(package: Path, monkeypatch) -> None:
    caches = _caches(package)

    def refuse(*args, **kwargs):
        raise PermissionError("read-only")

    monkeypatch.setattr(Path, "unlink", refuse)
    assert not refresh(package)
    assert all(p.exists() for p in caches)


def test_the_installed_package_has_its_digest_recorded() -> None:
    stamp = kernel_cache.PACKAGE / DIGEST_FILE
    assert stamp.read_text() == kernel_cache.source_digest()


def test_caches_under_numba_cache_dir_are_refreshed_too(package: Path, tmp_path: Path) -> None:
    """With ``NUMBA_CACHE_DIR`` numba caches in a folder per source directory there; a changed
    constant left those caches in place and the edited kernel ran stale, without an error."""
    cache_dir = tmp_path / "numba-cache"
    folders = [cache_dir / kernel_cache.numba_folder(d) for d in (package, package / "sub")]
    made = []
    for folder in folders:
        folder.mkdir(parents=True)
        for name in ("kernels.run-10.py311.nbi", "kernels.run-10.py311.nbc", "notes.txt"):
            (folder / name).write_text("machine code")
            made.append(folder / name)
    assert refresh(package, str(cache_dir))
    assert [p.name for p in made if p.exists()] == ["notes.txt", "notes.txt"]
    stamp = cache_dir / (kernel_cache.numba_folder(package) + ".sha256")
    assert stamp.read_text() == kernel_cache.source_digest(package)
    (folders[0] / "kernels.run-10.py311.nbi").write_text("machine code")
    assert not refresh(package, str(cache_dir))
    assert (folders[0] / "kernels.run-10.py311.nbi").exists()
    (package / "constants.py").write_text("LIMIT = 2.0\n")
    assert refresh(package, str(cache_dir))
    assert not (folders[0] / "kernels.run-10.py311.nbi").exists()


def test_the_folder_is_the_one_numba_uses(package: Path) -> None:
    """:func:`numba_folder` names the folder as the installed numba's locator does."""
    from numba.core.caching import UserProvidedCacheLocator

    source = package / "sub" / "body.py"
    expected = UserProvidedCacheLocator.get_suitable_cache_subpath(str(source))
    assert kernel_cache.numba_folder(source.parent) == expected


@pytest.mark.parametrize(
    "numba_import",
    [
        "from numba import njit\n",
        "from numba.extending import overload\n",
        "import numba as nb\n",
        "def lazy():\n    import numba\n",
        "try:\n    from numba import njit\nexcept ImportError:\n    pass\n",
    ],
    ids=["from", "from-submodule", "as", "in-a-function", "indented-from"],
)
def test_every_form_of_a_numba_import_makes_a_compiled_source(package: Path, numba_import):
    """A module that imports numba in any form (``from numba import``, indented in a function
    or a ``try``), imported by no other numba module, is compiled; the constants it reads are
    then compiled into it and a change of theirs drops the caches."""
    (package / "solo.py").write_text(numba_import + "from imm_gym.limits import CAP\n")
    (package / "limits.py").write_text("CAP = 1.0\n")
    names = [p.relative_to(package).as_posix() for p in compiled_sources(package)]
    assert {"solo.py", "limits.py"} <= set(names)
    assert refresh(package)
    caches = _caches(package)
    (package / "limits.py").write_text("CAP = 2.0\n")
    assert refresh(package)
    assert not any(p.exists() for p in caches)


def test_numba_cache_dir_is_read_from_the_environment(package: Path, tmp_path, monkeypatch):
    """``refresh()`` as run on import (no argument) takes ``NUMBA_CACHE_DIR`` from the
    environment: the caches numba keeps there are dropped and their digest recorded beside
    them."""
    cache_dir = tmp_path / "numba-env-cache"
    folder = cache_dir / kernel_cache.numba_folder(package)
    folder.mkdir(parents=True)
    (folder / "kernels.run-10.py311.nbi").write_text("machine code")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache_dir))
    assert refresh(package)
    assert not (folder / "kernels.run-10.py311.nbi").exists()
    stamp = cache_dir / (kernel_cache.numba_folder(package) + ".sha256")
    assert stamp.read_text() == kernel_cache.source_digest(package)
