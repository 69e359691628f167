"""Shared fixtures: the `polnlos` binary the bindings are compared with, and
the daemon the client talks to (both handed in by tests/daemon/python.rs)."""

import os
import shutil
import subprocess

import pytest


@pytest.fixture(scope="session")
def cli():
    """Runs the polnlos CLI (POLNLOS_BIN, else `polnlos` on PATH)."""
    exe = os.environ.get("POLNLOS_BIN") or shutil.which("polnlos")
    if not exe:
        pytest.fail("set POLNLOS_BIN to the polnlos binary (tests/daemon/python.rs does)")

    def run(*args):
        r = subprocess.run([exe, *map(str, args)], capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, f"polnlos {' '.join(map(str, args))}: {r.stderr}"
        return r

    return run


@pytest.fixture(scope="session")
def daemon_url():
    """The URL of a running `polnlos serve` with the fake camera."""
    url = os.environ.get("POLNLOS_URL")
    if not url:
        pytest.fail("set POLNLOS_URL to a running polnlos daemon (tests/daemon/python.rs starts one)")
    return url
