"""data/images/manifest.json against the shipped images (no network): every
PNG listed with its hash and every listed file present, 8-bit RGB with sides
multiples of 8, train / val / test disjoint by source photograph, no file from
the packages reserved for independent evaluation, and the validation set
large and varied enough. The manifest is written by tools/data/make_photos.py."""
import hashlib
import importlib.util
import json
import struct
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
IMAGES = REPO / "data" / "images"
RESERVED = {"mate-backgrounds", "plasma-workspace-wallpapers"}
FREE_LICENCES = {"CC0-1.0", "public-domain", "CC-BY-2.0", "CC-BY-4.0", "CC-BY-SA-3.0", "CC-BY-SA-4.0",
                 "GPL-2.0-or-later"}


@pytest.fixture(scope="module")
def manifest():
    return json.loads((IMAGES / "manifest.json").read_text())


def png_header(path: Path):
    """(width, height, bit depth, colour type) from the IHDR chunk."""
    data = path.read_bytes()[:33]
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", path
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    return width, height, depth, colour


def test_every_file_listed_with_its_hash(manifest):
    listed = {e["file"]: e for e in manifest["images"]}
    assert len(listed) == len(manifest["images"]), "a file listed twice"
    on_disk = {p.relative_to(IMAGES).as_posix() for split in ("train", "val", "test")
               for p in (IMAGES / split).glob("*") if p.is_file()}
    assert on_disk - set(listed) == set(), "files missing from manifest.json"
    assert set(listed) - on_disk == set(), "listed files missing from data/images"
    for name, e in listed.items():
        assert e["split"] == name.split("/")[0]
        assert hashlib.sha256((IMAGES / name).read_bytes()).hexdigest() == e["sha256"], name


def test_8bit_rgb_sides_multiple_of_8(manifest):
    for e in manifest["images"]:
        w, h, depth, colour = png_header(IMAGES / e["file"])
        assert (depth, colour) == (8, 2), f"{e['file']}: not 8-bit RGB"
        assert w % 8 == 0 and h % 8 == 0, e["file"]
        assert [w, h] == [e["width"], e["height"]], e["file"]
        x, y, cw, ch = e["crop"]
        f = e["downscale"]
        assert [cw // f, ch // f] == [w, h] and cw % f == 0 and ch % f == 0, e["file"]
        sw, sh = e["source_size"]
        assert 0 <= x and 0 <= y and x + cw <= sw and y + ch <= sh, e["file"]


def test_splits_disjoint_by_source_photograph(manifest):
    splits = {}
    for e in manifest["images"]:
        splits.setdefault((e["package"], e["member"]), set()).add(e["split"])
    shared = {k: v for k, v in splits.items() if len(v) > 1}
    assert not shared, f"source photographs in more than one split: {shared}"


def test_no_reserved_package(manifest):
    assert set(manifest["reserved_packages"]) == RESERVED
    for e in manifest["images"]:
        assert e["package"] not in RESERVED, e["file"]
        assert not any(r in e["member"] or r in e["archive"] for r in RESERVED), e["file"]
    for a in manifest["archives"].values():
        assert a["name"] not in RESERVED
    # The generator refuses them by name.
    spec = importlib.util.spec_from_file_location("make_photos", REPO / "tools" / "data" / "make_photos.py")
    make_photos = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_photos)
    assert make_photos.RESERVED == RESERVED
    for name in RESERVED:
        with pytest.raises(SystemExit):
            make_photos.refuse_reserved(name)


def test_provenance_complete(manifest):
    archives = {(a["name"], a["version"], a["file"], a["sha256"]) for a in manifest["archives"].values()}
    for e in manifest["images"]:
        assert e["licence"] in FREE_LICENCES, e["file"]
        assert e["author"] and e["licence_note"] and e["member"], e["file"]
        assert (e["package"], e["version"], e["archive"], e["archive_sha256"]) in archives, e["file"]
        assert len(e["archive_sha256"]) == 64 and len(e["sha256"]) == 64


def test_set_sizes(manifest):
    by = {}
    for e in manifest["images"]:
        by.setdefault(e["split"], []).append(e)
    assert len(by["val"]) >= 8 and len({e["package"] for e in by["val"]}) >= 4
    assert len(by["train"]) >= 24 and len({e["package"] for e in by["train"]}) >= 4
    assert sorted(e["file"] for e in by["test"]) == ["test/astronaut.png", "test/hubble.png"]
    total = sum((IMAGES / e["file"]).stat().st_size for e in manifest["images"])
    assert total < 15 * 2 ** 20, total
