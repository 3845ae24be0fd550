"""The browser HMI's third-party JavaScript: fetched from the npm registry, copied into the package.

    python tools/vendor_js.py                 # fetch every package at its recorded version again
    python tools/vendor_js.py uplot@1.6.33    # move one package to another version
    python tools/vendor_js.py --check         # offline: every vendored file is the one recorded

The HMI is static files shipped inside `pbo_runtime` (no build step, no CDN, works offline), so
its libraries live in `pbo_runtime/hmi/vendor/`, one folder per package. What is there,
from which version, under which licence and why, is written in `vendor/vendored.json`: this
script is the only writer of the folders, and reads the manifest for what to copy. It runs
`npm pack NAME@VERSION` (the registry's own tarball, its integrity checked by npm), copies the
files the manifest names and the package's licence, and records the licence from the package's
own package.json and each file's SHA-256. `--check` is what the tests run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Any

VENDOR = Path(__file__).resolve().parent.parent / "pbo_runtime" / "hmi" / "vendor"
MANIFEST = VENDOR / "vendored.json"
LICENCE_FILES = ("LICENSE", "LICENSE.md", "LICENCE", "license")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load() -> dict[str, Any]:
    return json.loads(MANIFEST.read_text(encoding="utf-8"))


def fetch(package: dict[str, Any], version: str) -> None:
    """Copy `package`'s files at `version` from the registry into its folder; record what was copied."""
    name = package["name"]
    with tempfile.TemporaryDirectory(prefix="pbo-vendor-") as scratch:
        packed = subprocess.run(["npm", "pack", "--json", f"{name}@{version}"], cwd=scratch, capture_output=True,
                                text=True, check=False)
        if packed.returncode != 0:
            sys.exit(f"npm pack {name}@{version} failed: {packed.stderr.strip().splitlines()[-1:] or packed.returncode}")
        [described] = json.loads(packed.stdout)
        with tarfile.open(Path(scratch) / described["filename"]) as tarball:
            tarball.extractall(scratch, filter="data")
        unpacked = Path(scratch) / "package"
        declared = json.loads((unpacked / "package.json").read_text(encoding="utf-8"))
        licence = next((unpacked / f for f in LICENCE_FILES if (unpacked / f).is_file()), None)
        if licence is None:
            sys.exit(f"{name}@{version} ships no licence file ({', '.join(LICENCE_FILES)}): not vendored")
        folder = VENDOR / name
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        shutil.copyfile(licence, folder / "LICENSE")
        hashes = {"LICENSE": sha256(folder / "LICENSE")}
        for source, target in package["files"].items():
            if not (unpacked / source).is_file():
                sys.exit(f"{name}@{version} has no {source}: update 'files' in {MANIFEST.name}")
            shutil.copyfile(unpacked / source, folder / target)
            hashes[target] = sha256(folder / target)
    package.update(version=declared["version"], license=declared.get("license", "see LICENSE"),
                   integrity=described["integrity"], sha256=hashes)


def check() -> list[str]:
    """What differs between the vendor folder and the manifest (nothing: an empty list)."""
    problems = []
    manifest = load()
    listed = {package["name"] for package in manifest["packages"]}
    for folder in sorted(p for p in VENDOR.iterdir() if p.is_dir()):
        if folder.name not in listed:
            problems.append(f"vendor/{folder.name} is not in {MANIFEST.name}")
    for package in manifest["packages"]:
        for field in ("name", "version", "license", "why", "files", "integrity", "sha256"):
            if not package.get(field):
                problems.append(f"{package.get('name', '?')}: no '{field}' in {MANIFEST.name}")
        for target, digest in package.get("sha256", {}).items():
            path = VENDOR / package["name"] / target
            if not path.is_file():
                problems.append(f"vendor/{package['name']}/{target} is missing")
            elif sha256(path) != digest:
                problems.append(f"vendor/{package['name']}/{target} is not the file of {package['name']}@{package['version']}")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", metavar="NAME@VERSION", help="packages to move to another version")
    parser.add_argument("--check", action="store_true", help="only check the vendored files against the manifest")
    arguments = parser.parse_args(argv)
    if arguments.check:
        problems = check()
        for problem in problems:
            print(problem, file=sys.stderr)
        return 1 if problems else 0
    manifest = load()
    by_name = {package["name"]: package for package in manifest["packages"]}
    wanted = dict(spec.rpartition("@")[::2] for spec in arguments.packages) if arguments.packages else {
        name: package["version"] for name, package in by_name.items()}
    for name, version in wanted.items():
        if name not in by_name:
            sys.exit(f"{name} is not vendored: add it to {MANIFEST} with its 'files' and 'why' first")
        fetch(by_name[name], version)
        print(f"vendored {name}@{by_name[name]['version']} ({by_name[name]['license']})")
    MANIFEST.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
