"""`nedrt-train`, the trainer's command: one subcommand per module CLI.

    nedrt-train train  --preset half --out models/runs/half      # python -m nedrt_train.train
    nedrt-train design --target allsharp --out models/runs/d     # python -m nedrt_train.design
    nedrt-train export --run models/runs/half --name half         # python -m nedrt_train.export
    nedrt-train dcnn --teacher out/teacher --out models/runs/dcnn # python -m nedrt_train.distill
    nedrt-train ceiling --teacher out/teacher                     # python -m nedrt_train.ceiling
    nedrt-train judge --candidate out/devcheck/dcnn-full.onnx     # python -m nedrt_train.judge

Each subcommand takes exactly the arguments of its module (`nedrt-train
train --help`); `python -m nedrt_train.X` and `python -m nedrt_train X` run
the same code. Run from the repository root, or pass `--calib FILE` (and
`--images DIR`): the package looks up nothing beside itself.
"""
import importlib
import sys

#: Subcommand → (module, one line of help).
COMMANDS = {
    "train": ("nedrt_train.train", "joint DOE + D-CNN training (DDP under torchrun)"),
    "design": ("nedrt_train.design", "the DOE stage: a radial DOE for a Wiener prefilter"),
    "export": ("nedrt_train.export", "a training run as ONNX, DOE files and a model card"),
    "dcnn": ("nedrt_train.distill", "the D-CNN for a frozen DOE, on nedrt's exact objective and optimum"),
    "ceiling": ("nedrt_train.ceiling", "the per-frame optimum of the evaluation's mean PSNR: what no preprocessor beats"),
    "judge": ("nedrt_train.judge", "the shipping rule: a returned network against its Wiener and the shipped one"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"  {name:<{width}}  {what}" for name, (_, what) in COMMANDS.items()]
    return ("usage: nedrt-train {" + ",".join(COMMANDS) + "} [ARGS...]\n\n"
            "The nedrt trainer. Subcommands (`nedrt-train COMMAND --help` for their arguments):\n"
            + "\n".join(lines) + "\n")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        sys.stdout.write(usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        sys.stderr.write(usage() + f"\nnedrt-train: error: unknown command {name!r}\n")
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    module.main(rest, prog=f"nedrt-train {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
