"""The HMI's third-party JavaScript is exactly what its manifest records: package, version, licence, files."""

from __future__ import annotations

import json

from tools import vendor_js


def test_every_vendored_file_is_the_one_its_manifest_records_with_version_and_licence():
    assert vendor_js.check() == []
    for package in vendor_js.load()["packages"]:
        assert (vendor_js.VENDOR / package["name"] / "LICENSE").is_file()
        assert package["version"] and package["license"] and package["why"]


def test_a_vendored_file_changed_by_hand_is_named(tmp_path, monkeypatch):
    vendor = tmp_path / "vendor"
    (vendor / "tiny").mkdir(parents=True)
    (vendor / "tiny" / "tiny.mjs").write_text("export const x = 1;\n")
    (vendor / "tiny" / "LICENSE").write_text("MIT\n")
    recorded = {"tiny.mjs": vendor_js.sha256(vendor / "tiny" / "tiny.mjs"),
                "LICENSE": vendor_js.sha256(vendor / "tiny" / "LICENSE")}
    manifest = {"packages": [{"name": "tiny", "version": "1.0.0", "license": "MIT", "why": "a test", "integrity": "sha512-x",
                              "files": {"tiny.mjs": "tiny.mjs"}, "sha256": recorded}]}
    (vendor / "vendored.json").write_text(json.dumps(manifest))
    monkeypatch.setattr(vendor_js, "VENDOR", vendor)
    monkeypatch.setattr(vendor_js, "MANIFEST", vendor / "vendored.json")
    assert vendor_js.check() == []
    (vendor / "tiny" / "tiny.mjs").write_text("export const x = 2;\n")
    (vendor / "stray").mkdir()
    assert vendor_js.check() == ["vendor/stray is not in vendored.json", "vendor/tiny/tiny.mjs is not the file of tiny@1.0.0"]
