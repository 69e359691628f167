#!/usr/bin/env python3
"""The minimum supported Rust version, checked without a second toolchain.

The `rust-version` each of our Cargo.toml files declares must be at least
the highest `rust-version` of the crates its locked build compiles (normal,
build and dev dependencies, default features, this platform): otherwise a
lab's older toolchain fails inside a dependency with an error that does not
say why. Our own code's use of newer std APIs is clippy's
`incompatible_msrv` lint, which reads the same key (scripts/lint.sh runs
clippy with -D warnings).
"""
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent


def version(text):
    parts = [int(x) for x in text.split(".")]
    return tuple(parts + [0] * (3 - len(parts)))


def check(directory):
    tree = subprocess.run(
        ["cargo", "tree", "--locked", "-e", "normal,build,dev", "--prefix", "none", "--format", "{p}"],
        cwd=directory, check=True, capture_output=True, text=True,
    ).stdout
    used = {line.split(" (")[0].strip().replace(" v", " ", 1) for line in tree.splitlines() if line.strip()}
    meta = json.loads(subprocess.run(
        ["cargo", "metadata", "--locked", "--format-version", "1"],
        cwd=directory, check=True, capture_output=True, text=True,
    ).stdout)
    manifest = str((directory / "Cargo.toml").resolve())
    ours = next(p for p in meta["packages"] if p["manifest_path"] == manifest)
    declared = ours.get("rust_version")
    if declared is None:
        return f"{ours['name']}: Cargo.toml declares no rust-version"
    needs = [
        (version(p["rust_version"]), p["name"], p["version"])
        for p in meta["packages"]
        if p.get("rust_version") and f"{p['name']} {p['version']}" in used and p["id"] != ours["id"]
    ]
    need, name, at = max(needs, default=((0, 0, 0), "", ""))
    shown = ".".join(map(str, need))
    if need > version(declared):
        return (f"{ours['name']}: rust-version {declared} is below what its locked dependencies need: "
                f"{name} {at} needs {shown}; raise rust-version in its Cargo.toml (or hold that crate back in Cargo.lock)")
    print(f"{ours['name']}: rust-version {declared} covers its locked dependencies (the highest: {name} {at}, {shown})")
    return None


failures = [f for f in (check(ROOT), check(ROOT / "python")) if f]
for f in failures:
    print(f, file=sys.stderr)
sys.exit(1 if failures else 0)
