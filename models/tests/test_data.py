"""The trainer's photographs: every training crop is loaded, the validation
photographs come from data/images/val and share no file with training."""
import numpy as np

from nedrt_train.data import TRAIN_DIR, VAL_DIR, TEST_DIR, TrainingImages, load_photos, validation_images, \
    validation_photos


def test_training_uses_every_train_photo():
    names = sorted(p.name for p in TRAIN_DIR.glob("*.png"))
    assert len(names) >= 24
    assert len(TrainingImages(256, seed=0).photos) == len(names)


def test_validation_photos_are_the_val_set():
    val = validation_photos()
    assert val.shape[0] == len(list(VAL_DIR.glob("*.png"))) >= 8
    assert val.shape[1] == 3 and float(val.min()) >= 0 and float(val.max()) <= 1
    crops = validation_photos(64)
    assert crops.shape == (val.shape[0], 3, 64, 64)
    # validation_images: 4 procedural images, then the same centre crops.
    both = validation_images(64)
    assert both.shape[0] == 4 + val.shape[0]
    assert np.array_equal(both[4:].numpy(), crops.numpy())
    # No validation or test photograph is a training photograph.
    train = {p.tobytes() for p in load_photos(TRAIN_DIR)}
    assert not any(p.tobytes() in train for p in load_photos(VAL_DIR) + load_photos(TEST_DIR))
