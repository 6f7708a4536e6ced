"""The D-CNN stage's configuration (distill.py runs it, `nedrt-train dcnn`
its command line, one flag per field): what a run trains, where its data
lie and where it runs; and `is_finished`, whether a run's schedule has run
out, which the run (distill.py) and its export (distill_export.py) both ask.
A checkpoint stores the fields as a dict, so a resumed run rebuilds this."""
from dataclasses import dataclass


@dataclass
class DistillConfig:
    width: int = 16
    levels: int = 4
    patch: int = 128
    batch: int = 8
    steps: int = 6000
    lr: float = 1e-3
    # Weight of the distance to the teacher (mean squared, display units)
    # against the objective's mean squared error (retinal, per depth).
    distill: float = 1.0
    # Weight of the squared excursion outside [0, 1] of the raw output.
    range_penalty: float = 1.0
    # "mse": the summed squared error over the depths (what `optimal`
    # minimises); "psnr": the mean over the depths of the per-depth PSNR,
    # per frame (what the evaluation's headline averages).
    loss: str = "mse"
    # With --loss psnr: weight of the mean per-depth PSNR against the sharp
    # image (kernels from DIR/train-sharp, nedrt prefilter
    # --prefilter optimal@sharp --operator …) beside the one against the target.
    sharp_weight: float = 0.0
    seed: int = 0
    teacher: str | None = None
    images: str | None = None
    validate_every: int = 500
    checkpoint_every: int = 250
    threads: int = 0
    # Start from the network of another run's checkpoint (a fresh optimiser
    # and schedule): distil first, then fine-tune on the metric.
    init: str | None = None
    # The residual's base: the input ("input", the runtime's network
    # I + UNet(I)) or the Wiener prefilter's output of the design ("wiener",
    # DIR/train-wiener and DIR/val-wiener; display = W(I) + UNet(I) − I,
    # the last layer started at zero so that training starts at the Wiener).
    base: str = "input"
    # The network's input: the photograph ("image") or the design's Wiener
    # output before the clamp ("wiener-raw", DIR/train-wiener-raw and
    # DIR/val-wiener-raw from nedrt prefilter --prefilter native --unclamped;
    # display = x + UNet(x) for x = W(I), the last layer started at zero,
    # so that training starts at the clamped Wiener and the network sees
    # where and by how much the clamp cuts).
    input: str = "image"
    # Gradient of the panel's clamp: "zero" outside [0, 1] (the clamp's
    # own) or "straight" (straight-through: the loss at the clamped image,
    # passed to the raw output as if unclamped, so that a value the clamp
    # cuts still learns which way it should move).
    clamp_grad: str = "zero"
    # The folder under --teacher whose display images are distilled
    # ("train": nedrt's optimum; "train-ceiling": nedrt-train ceiling
    # --split train --write, the optimum of the evaluation's mean PSNR).
    teacher_set: str = "train"
    # How the distance to the teacher is measured: in display values
    # ("display"), or as the eye sees it ("perceived": the mean squared
    # difference of the perceived images summed over the depths, through the
    # objective's normal kernel). The ceiling's display image carries
    # content the optics do not pass (its start's, unconstrained by the
    # objective); "perceived" does not ask the network to learn that.
    distill_metric: str = "display"
    # Where the step runs ("cpu", "cuda", "cuda:1", "meta" in tests): the
    # network, the objective's spectra, the photographs and their teachers
    # all live there; a checkpoint resumes on any device.
    device: str = "cpu"
    # Mixed precision of the network ("off", or "bf16": its convolutions
    # under autocast, float32 accumulation; the residual sum, the clamp and
    # the objective's FFTs stay float32, so the loss is computed in full
    # precision from a display image whose residual is good to bf16's 3
    # significant digits).
    amp: str = "off"
    # A wall-clock budget of the run, seconds (0: none): the schedule's
    # cosine follows the time spent instead of the steps, and the run stops
    # (checkpointed, validated) when the budget is spent or at `steps`.
    time_budget: float = 0.0
    # --batch 0: the largest batch of patches (a power of two, at most this)
    # whose step fits in the device's memory, probed before the first step.
    max_batch: int = 64


def is_finished(cfg: DistillConfig, step: int, seconds: float) -> bool:
    """At its last step, or its time budget spent (its schedule has run out)."""
    return step >= cfg.steps or (cfg.time_budget > 0 and seconds >= cfg.time_budget)
