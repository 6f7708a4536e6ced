#!/usr/bin/env python3
"""Field zones against one PSF for the whole image (docs/evaluation.md,
"Through a real eye"): `nedrt sim` through an eye pupil at several field
angles, each photograph rendered once with --field-zones 1 (the isoplanatic
approximation the eyes study makes) and once with --field-zones auto, and
the scores side by side.

    python3 tools/eyes/zones.py --out docs/eyes/zones.md

Each run's text is kept beside the table (zones.json), so a row can be
traced to its command.
"""

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# (label, nedrt arguments) of the systems compared.
SYSTEMS = [
    ("conventional", ["--method", "conventional"]),
    ("ai", ["--method", "ai"]),
    ("doe+wiener multifocal", ["--design", "multifocal", "--method", "doe+wiener"]),
    ("doe+wiener realeye", ["--design", "realeye", "--method", "doe+wiener"]),
]


def score(text: str, what: str) -> float:
    m = re.search(rf"^{what}\s+PSNR\s+([-\d.]+) dB", text, re.M)
    if not m:
        raise SystemExit(f"no '{what}' line in:\n{text}")
    return float(m.group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nedrt", default=str(REPO / "target/release/nedrt"))
    ap.add_argument("--images", default="data/images/val/airport.png,data/images/val/coast.png")
    ap.add_argument("--fields-deg", default="0,10,20")
    ap.add_argument("--pupil-mm", default="4")
    ap.add_argument("--accom", default="1.5")
    ap.add_argument("--out", type=Path, default=REPO / "docs/eyes/zones.md")
    args = ap.parse_args()
    images = [i for i in args.images.split(",") if i]
    fields = [f for f in args.fields_deg.split(",") if f]
    runs = []
    for image in images:
        for field in fields:
            for label, system in SYSTEMS:
                row = {"image": Path(image).name, "field_deg": float(field), "system": label}
                for zones in ("1", "auto"):
                    cmd = [args.nedrt, "sim", *system, "--accom", args.accom, "--input", image,
                           "--pupil-mm", args.pupil_mm, "--field-deg", field, "--field-zones", zones,
                           "--out", str(Path("/tmp") / "nedrt-zones.png")]
                    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
                    if p.returncode:
                        sys.exit(f"{' '.join(cmd)}: {p.stderr.strip()}")
                    zline = re.search(r"^zones\s+(.*)$", p.stdout, re.M)
                    row[zones] = {"vs_sharp": score(p.stdout, "vs sharp"),
                                  "vs_target": score(p.stdout, "vs target"),
                                  "zones": zline.group(1) if zline else "",
                                  "command": " ".join(cmd[1:])}
                    print(f"{row['image']} {field}° {label} zones {zones}: "
                          f"{row[zones]['vs_sharp']:.2f} / {row[zones]['vs_target']:.2f} dB "
                          f"({row[zones]['zones'].split(':')[0]})", flush=True)
                runs.append(row)
    lines = [
        "# Field zones against one PSF for the whole image",
        "",
        f"`python3 tools/eyes/zones.py` (`nedrt sim --accom {args.accom} --pupil-mm {args.pupil_mm}"
        " --field-deg F --field-zones 1|auto`, eye relief 15 mm, no eye LCA; each photograph's centre at F).",
        "PSNR dB vs sharp / vs target; Δ = zones − one PSF.",
        "",
        "| photograph | field | system | one PSF | zones | Δ vs sharp / vs target | zones chosen |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in runs:
        one, auto = r["1"], r["auto"]
        chosen = auto["zones"].split(" for ")[0].split(" (")[0]
        lines.append(
            f"| {r['image']} | {r['field_deg']:g}° | {r['system']} | {one['vs_sharp']:.2f} / {one['vs_target']:.2f} | "
            f"{auto['vs_sharp']:.2f} / {auto['vs_target']:.2f} | "
            f"{auto['vs_sharp'] - one['vs_sharp']:+.2f} / {auto['vs_target'] - one['vs_target']:+.2f} | {chosen} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(args.out)
    js = args.out.with_suffix(".json")
    tmp = js.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(runs, indent=1))
    tmp.replace(js)
    print(f"wrote {args.out}, {js}")


if __name__ == "__main__":
    main()
