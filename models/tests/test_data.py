"""The trainer's photographs: every training crop is loaded, the validation
photographs come from data/images/val and share no file with training."""
from pathlib import Path

import numpy as np
import pytest

from nedrt_train.data import TrainingImages, load_photos, resolve_root, validation_images, validation_photos

IMAGES = Path(__file__).resolve().parents[2] / "data" / "images"
TRAIN_DIR, VAL_DIR, TEST_DIR = IMAGES / "train", IMAGES / "val", IMAGES / "test"


def test_training_uses_every_train_photo():
    names = sorted(p.name for p in TRAIN_DIR.glob("*.png"))
    assert len(names) >= 24
    assert len(TrainingImages(256, 0, TRAIN_DIR).photos) == len(names)


def test_validation_photos_are_the_val_set():
    val = validation_photos(VAL_DIR)
    assert val.shape[0] == len(list(VAL_DIR.glob("*.png"))) >= 8
    assert val.shape[1] == 3 and float(val.min()) >= 0 and float(val.max()) <= 1
    crops = validation_photos(VAL_DIR, 64)
    assert crops.shape == (val.shape[0], 3, 64, 64)
    # validation_images: 4 procedural images, then the same centre crops.
    both = validation_images(64, VAL_DIR)
    assert both.shape[0] == 4 + val.shape[0]
    assert np.array_equal(both[4:].numpy(), crops.numpy())
    # No validation or test photograph is a training photograph.
    train = {p.tobytes() for p in load_photos(TRAIN_DIR)}
    assert not any(p.tobytes() in train for p in load_photos(VAL_DIR) + load_photos(TEST_DIR))


def test_image_folders_are_arguments_and_a_missing_one_is_named(tmp_path):
    # The default root is data/images under the current directory, not beside the package.
    assert resolve_root(cwd=IMAGES.parents[1]) == IMAGES
    with pytest.raises(FileNotFoundError, match=str(tmp_path / "data" / "images")):
        resolve_root(cwd=tmp_path)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        TrainingImages(32, 0, tmp_path / "nowhere")
