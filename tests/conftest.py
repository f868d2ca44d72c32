"""Shared fixtures: a seeded rng and the path of the real data beside the checkout."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone ../shared beside the project)")
    return SHARED_DATA


@pytest.fixture
def readonly_folder(tmp_path: Path) -> Iterator[Path]:
    """An empty folder nobody can write into (mode 0555; as root, also ``chattr +i``, since root
    writes through file modes). Skips when the folder cannot be made read-only."""
    ro = tmp_path / "readonly"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    immutable = False
    if os.geteuid() == 0:
        chattr = shutil.which("chattr")
        if chattr is None or subprocess.run([chattr, "+i", str(ro)], check=False).returncode:
            ro.chmod(stat.S_IRWXU)
            pytest.skip("running as root and the folder cannot be made immutable (chattr +i)")
        immutable = True
    try:
        yield ro
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(ro)], check=False)
        ro.chmod(stat.S_IRWXU)
