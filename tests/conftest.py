"""Shared fixtures: a seeded rng and the path of the real data beside the checkout."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


def pytest_configure(config: pytest.Config) -> None:
    """Tests stop the kinefuse processes they start with SIGINT, as Ctrl-C does. A shell that
    starts the suite in the background (``cmd &`` in a script or a subshell, ``nohup``) sets
    SIGINT to ignored; every child inherits that and Python keeps it, so a demo, a viewer or a
    simulation the tests started ran on through its SIGINT and the test failed (seen:
    ``test_ctrl_c_stops_every_process_and_keeps_the_old_outputs``). Python's own handler here
    makes the children start with the default again."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone ../shared beside the project)")
    return SHARED_DATA


@pytest.fixture
def read_only_copy(tmp_path):
    """``read_only_copy(*files) -> folder``: copies ``files`` into a folder that cannot be written.

    For an ordinary user that is a folder (and files) with the write bits removed. root ignores
    write bits, so as root the folder is a small tmpfs mounted read-only: real read-only media,
    as a write-protected card or a network share would be.
    """
    import os
    import shutil
    import stat
    import subprocess

    made: list[tuple[str, Path]] = []

    def make(*files: Path) -> Path:
        folder = tmp_path / f"ro{len(made)}"
        folder.mkdir()
        if os.geteuid() != 0:
            for f in files:
                shutil.copy2(f, folder / f.name)
                (folder / f.name).chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
            folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
            made.append(("chmod", folder))
            return folder
        size = sum(f.stat().st_size for f in files) + (1 << 20)
        mount = ["mount", "-t", "tmpfs", "-o", f"size={size}", "kinefuse-test", str(folder)]
        if subprocess.run(mount, capture_output=True).returncode != 0:
            pytest.skip("running as root, and cannot mount a read-only tmpfs to stand for media")
        made.append(("mount", folder))
        for f in files:
            shutil.copy2(f, folder / f.name)
        subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True)
        return folder

    yield make
    for kind, folder in reversed(made):
        if kind == "mount":
            subprocess.run(["umount", str(folder)], check=False)
        else:
            folder.chmod(stat.S_IRWXU)
            for f in folder.iterdir():
                f.chmod(stat.S_IRUSR | stat.S_IWUSR)


@pytest.fixture
def readonly_folder(read_only_copy) -> Path:
    """An empty folder nobody can write into (see :func:`read_only_copy`)."""
    return read_only_copy()
