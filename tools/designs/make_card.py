"""The card of a display design: the recipe and wall time of its DOE stage
(design.json), the data it saw, and the validation table measured by
`nedrt eval` on data/images/val (designs/NAME/eval/eval.json), with the
acceptance lines of issue 14 checked against the baselines of the same run.

    python tools/designs/make_card.py NAME RUN_DIR DESIGN_DIR
"""
import hashlib
import json
import os
import sys
from pathlib import Path


def eye_flags(config: dict) -> str:
    """The DOE stage's eye options as its command line gives them."""
    flags = ""
    if config.get("pupils_mm"):
        flags += " --pupils-mm " + ",".join(f"{p:g}" for p in config["pupils_mm"])
    if config.get("eye_lca") is not None:
        flags += " --eye-lca " + ("on" if config["eye_lca"] else "off")
    return flags


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def headline(method: dict, key: str) -> dict:
    h = method[key]
    return {"mean_psnr_db": h["mean"]["psnr_db"], "worst_psnr_db": h["worst"]["psnr_db"],
            "mean_ssim": h["mean"]["ssim"]}


def main(name: str, run: Path, out: Path):
    design = json.loads((run / "design.json").read_text())
    ev = json.loads((out / "eval" / "eval.json").read_text())
    methods = {m["method"]: m for m in ev["methods"]}
    table = {m: {"vs_sharp": headline(r, "headline_vs_sharp"), "vs_target": headline(r, "headline_vs_target"),
                 "focus_cues": r.get("focus_cues")}
             for m, r in methods.items()}
    conv, ai, ours = table["conventional"], table["ai"], table["doe+wiener"]
    checks = []
    if design["target"] == "allsharp":
        checks.append(("mean vs sharp ≥ AI mean − 0.1 dB", ours["vs_sharp"]["mean_psnr_db"],
                       ai["vs_sharp"]["mean_psnr_db"] - 0.1))
        checks.append(("worst vs sharp ≥ AI worst + 1.0 dB", ours["vs_sharp"]["worst_psnr_db"],
                       ai["vs_sharp"]["worst_psnr_db"] + 1.0))
    else:
        checks.append(("worst vs sharp ≥ conventional worst + 2.0 dB", ours["vs_sharp"]["worst_psnr_db"],
                       conv["vs_sharp"]["worst_psnr_db"] + 2.0))
        checks.append(("mean vs target ≥ AI mean − 0.1 dB", ours["vs_target"]["mean_psnr_db"],
                       ai["vs_target"]["mean_psnr_db"] - 0.1))
    card = {
        "name": name,
        "target": design["target"],
        "recipe": {"command": f"python -m nedrt_train.design --target {design['target']} --steps {design['steps']}"
                              f"{eye_flags(design['config'])} --name {name}",
                   "script": "tools/designs/make_designs.sh", "config": design["config"],
                   "spectrum_alpha": design["spectrum_alpha"]},
        "wall_time_s": design["wall_time_s"],
        "threads": design["threads"],
        "machine": os.uname().machine + ", " + (os.cpu_count() and f"{os.cpu_count()} cores" or "?"),
        "data": {"design": "fixed crops of data/images/train (data/images/SOURCES.md)",
                 "validation": ev["images"]},
        "wiener_k": design["wiener_k_linear"],
        "train_psnr_clamped": design.get("train_psnr_clamped"),
        "files": {p.name: sha(p) for p in sorted(out.glob("*.safetensors"))},
        "validation": {"calibration": ev["calibration"], "methods": table},
        "acceptance": [{"line": line, "value": round(v, 3), "needed": round(need, 3), "met": v >= need}
                       for line, v, need in checks],
    }
    tmp = out / "card.json.tmp"
    tmp.write_text(json.dumps(card, indent=1, ensure_ascii=False))
    tmp.replace(out / "card.json")
    for c in card["acceptance"]:
        print(f"{name}: {c['line']}: {c['value']} (needs {c['needed']}) {'met' if c['met'] else 'NOT met'}")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]))
