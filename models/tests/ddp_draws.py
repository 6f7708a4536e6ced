"""Helper of test_train.py's DDP resume test, run under torchrun with two
processes: each rank trains the smoke preset straight through to --steps in
OUT/straight and, in OUT/resumed, to --split, then resumes from that
checkpoint to --steps, recording its depth and batch draws; writes
OUT/draws-rankR.pt ({"straight"|"first"|"resumed": {step: (depth, batch)}})."""
import argparse
import dataclasses
from pathlib import Path

import torch
import torch.distributed as dist

from nedrt_train.train import PRESETS, finish, init_distributed, loop, setup


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--calib", required=True)
    ap.add_argument("--images", required=True)
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--split", type=int, default=2)
    args = ap.parse_args()
    assert init_distributed("cpu"), "run under torchrun with WORLD_SIZE > 1"
    rank = dist.get_rank()
    cfg = dataclasses.replace(PRESETS["smoke"], steps=args.steps, checkpoint_every=1,
                              calib=args.calib, images=args.images)
    draws = {}

    def recorder(name):
        def on_step(step, depth, batch):
            draws.setdefault(name, {})[step] = (depth, batch.clone())
        return on_step

    run = setup(cfg, args.out / "straight")
    loop(run, recorder("straight"))
    finish(run)
    run = setup(dataclasses.replace(cfg, steps=args.split), args.out / "resumed")
    loop(run, recorder("first"))
    finish(run)
    dist.barrier()  # rank 0 has written the checkpoint every rank resumes from
    run = setup(cfg, args.out / "resumed", resume=True)
    loop(run, recorder("resumed"))
    finish(run)
    torch.save(draws, args.out / f"draws-rank{rank}.pt")
    dist.barrier()  # no rank leaves the group while rank 0 still validates
    dist.destroy_process_group()


if __name__ == "__main__":
    main()
